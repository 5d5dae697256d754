"""Frozen value types: camera intrinsics with Brown distortion, rigid transforms, sensor packets and
RGB-D frames.

Array fields are converted to the documented dtype and made read-only on construction, so a frame
handed to a stage cannot be changed behind the caller's back. Equality compares arrays element-wise
(NaN never occurs in a valid instance).

Conventions (docs/reference/conventions.md): transforms are ``T_dst_from_src`` 4×4 float64 with
``p_dst = T_dst_from_src @ p_src``; camera frames are OpenCV (x right, y down, z forward); timestamps
are integer nanoseconds; depth in images is z-depth in metres.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from typing import Union

import numpy as np
from scipy.spatial.transform import Rotation

from collections.abc import Mapping

from rgbd_envmap.checks import check_array, check_flag, check_instance, check_number, check_range
from rgbd_envmap.errors import DTypeError, FrameError, InvalidInputError, NonFiniteError, RangeError, ShapeError

__all__ = [
    "Distortion",
    "Intrinsics",
    "RigidTransform",
    "DepthPacket",
    "ColourPacket",
    "SensorPacket",
    "Calibration",
    "RGBDFrame",
    "ORTHONORMAL_TOL",
    "MAX_IMAGE_PIXELS",
    "check_transform",
]

#: Largest accepted deviation of R^T R from the identity (and of det R from 1).
ORTHONORMAL_TOL = 1e-6

#: The largest image an :class:`Intrinsics` may describe: 2**26 pixels (64 Mpx, 8192 × 8192). The
#: per-pixel ray table alone (H × W × 3 float32) is 768 MiB at the bound.
MAX_IMAGE_PIXELS = 2**26


def _finite_float(value: object, name: str) -> float:
    """``value`` as a float: a :class:`DTypeError` unless it is a real number (not a bool or a
    string), a :class:`NonFiniteError` for NaN or infinity."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise DTypeError(f"{name}: expected a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise NonFiniteError(f"{name}: expected a finite value, got {value}")
    return value


def _timestamp(value: object, name: str) -> int:
    return int(check_number(value, name, integer=True))


def _mapping_get(d: Mapping, key: str, name: str) -> object:
    if key not in d:
        raise InvalidInputError(f"{name}: expected a key {key!r}, got keys {sorted(map(str, d))}")
    return d[key]


def check_transform(value: object, name: str, dst: str | None = None, src: str | tuple[str, ...] | None = None,
                    ) -> "RigidTransform":
    """Return ``value`` after checking that it is a :class:`RigidTransform` (:class:`DTypeError`) whose
    named frames are ``dst`` and ``src`` (a tuple: any of them), raising :class:`FrameError` otherwise.
    An unnamed frame (``""``) is taken as it comes, so a transform built without names passes.
    Costs about 1 µs."""
    if not isinstance(value, RigidTransform):
        raise DTypeError(f"{name}: expected a RigidTransform, got {type(value).__name__}")
    srcs = (src,) if isinstance(src, str) else src
    if (dst is not None and value.dst and value.dst != dst) or (srcs is not None and value.src and value.src not in srcs):
        want = f"T_{dst or '*'}_from_{'|'.join(srcs) if srcs else '*'}"
        raise FrameError(f"{name}: expected {want}, got T_{value.dst or '?'}_from_{value.src or '?'}")
    return value


def _frozen_array(obj: object, name: str, arr: np.ndarray) -> None:
    arr = np.array(arr, copy=True)
    arr.setflags(write=False)
    object.__setattr__(obj, name, arr)


class _ArrayEq:
    """Dataclass mixin: ``==`` compares every field, arrays by value and dtype."""

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) != isinstance(b, np.ndarray):  # an optional array and None
                return False
            if isinstance(a, np.ndarray):
                if a.dtype != b.dtype or not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class Distortion:
    """Brown–Conrady distortion in OpenCV order (k1, k2, p1, p2, k3).

    The ToF camera uses the 3-coefficient radial form (:meth:`radial`: k1, k2, k3, no tangential
    terms); the colour camera uses all five.
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, _finite_float(getattr(self, f.name), f"Distortion.{f.name}"))

    @classmethod
    def radial(cls, k1: float, k2: float, k3: float) -> "Distortion":
        """Brown's 3-coefficient radial polynomial (no tangential terms)."""
        return cls(k1=k1, k2=k2, p1=0.0, p2=0.0, k3=k3)

    @property
    def coefficients(self) -> np.ndarray:
        """(5,) float64 in OpenCV order, as ``cv2.projectPoints`` takes them."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def is_zero(self) -> bool:
        return not np.any(self.coefficients)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of an image of ``width`` × ``height`` pixels, plus Brown distortion.

    Pixel centres sit at integer coordinates (OpenCV): pixel (row v, column u) covers
    [u − 0.5, u + 0.5] × [v − 0.5, v + 0.5].

    The focal lengths are signed: u = fx·x′ + cx and v = fy·y′ + cy hold exactly as written in the
    camera frame the pose names, so fy < 0 means the image's rows run against the frame's +y (ICL-NUIM
    publishes fy = −480 for its POV-Ray renders: its camera frame has y up). Zero is rejected. Whatever
    needs a size in pixels from a focal length (a footprint, a stretch test, the field of view) uses
    |fx| and |fy|.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: Distortion = field(default_factory=Distortion)

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise RangeError(f"Intrinsics.{name}: expected a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.width * self.height > MAX_IMAGE_PIXELS:
            raise RangeError(f"Intrinsics.width×height: expected at most {MAX_IMAGE_PIXELS:,} pixels, got "
                             f"{self.width}×{self.height}; its ray table alone would take about "
                             f"{self.width * self.height * 12 / 2**30:.3g} GiB")
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, _finite_float(getattr(self, name), f"Intrinsics.{name}"))
        if self.fx == 0 or self.fy == 0:
            raise RangeError(f"Intrinsics.fx, fy: expected non-zero (signed) focal lengths, got fx={self.fx}, fy={self.fy}")
        check_instance(self.distortion, Distortion, "Intrinsics.distortion")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width), the shape of an image from this camera."""
        return (self.height, self.width)

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view in degrees of the undistorted pinhole (the sign of a
        focal length mirrors the image, not its extent: |fx|, |fy|)."""
        fx, fy = abs(self.fx), abs(self.fy)
        h = np.degrees(np.arctan(self.cx / fx + 0.5 / fx) + np.arctan((self.width - 0.5 - self.cx) / fx))
        v = np.degrees(np.arctan(self.cy / fy + 0.5 / fy) + np.arctan((self.height - 0.5 - self.cy) / fy))
        return float(h), float(v)

    @property
    def focal_px(self) -> float:
        """The mean focal length in pixels, 0.5 (|fx| + |fy|): a pixel's size on a surface facing the
        camera at distance r is about r / ``focal_px``."""
        return 0.5 * (abs(self.fx) + abs(self.fy))

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """The same camera resampled to ``width`` × ``height`` (pixel-centre convention kept)."""
        for name, value in (("width", width), ("height", height)):
            check_number(value, name, low=1, integer=True)
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            width, height, self.fx * sx, self.fy * sy,
            (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, self.distortion,
        )

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Intrinsics":
        check_instance(d, Mapping, "d")
        d = dict(d)
        dist = d.pop("distortion", {})
        check_instance(dist, Mapping, "d['distortion']")
        names = {f.name for f in dataclasses.fields(cls)} - {"distortion"}
        unknown, missing = set(map(str, d)) - names, names - set(map(str, d))
        if unknown or missing:
            raise InvalidInputError(f"d: expected the keys {sorted(names)} (and 'distortion'), got "
                                    f"{sorted(map(str, d))}" + (f"; missing {sorted(missing)}" if missing else ""))
        dist_names = {f.name for f in dataclasses.fields(Distortion)}
        if set(map(str, dist)) - dist_names:
            raise InvalidInputError(f"d['distortion']: expected keys among {sorted(dist_names)}, got {sorted(map(str, dist))}")
        return cls(distortion=Distortion(**dist), **d)


@dataclass(frozen=True, eq=False)
class RigidTransform(_ArrayEq):
    """A rigid transform ``T_dst_from_src`` as a 4×4 float64 matrix, validated on construction.

    ``dst`` and ``src`` optionally name the frames; when both operands of ``@`` name them, the
    composition checks that they chain (``T_a_from_b @ T_b_from_c``).
    """

    matrix: np.ndarray
    dst: str = ""
    src: str = ""

    def __post_init__(self) -> None:
        for name in ("dst", "src"):
            if not isinstance(getattr(self, name), str):
                raise DTypeError(f"RigidTransform.{name}: expected a frame name (str), got {getattr(self, name)!r}")
        m = check_array(self.matrix, "RigidTransform.matrix", shape=(4, 4), dtype="float").astype(np.float64)
        if not np.isfinite(m).all():
            raise NonFiniteError("RigidTransform.matrix: expected finite values, got NaN or inf")
        r = m[:3, :3]
        err = np.abs(r.T @ r - np.eye(3)).max()
        if err > ORTHONORMAL_TOL or abs(np.linalg.det(r) - 1.0) > ORTHONORMAL_TOL:
            raise InvalidInputError(
                f"RigidTransform.matrix: rotation is not orthonormal with det +1 "
                f"(max |RᵀR − I| = {err:.3g}, det = {np.linalg.det(r):.6f})"
            )
        if np.any(m[3] != [0.0, 0.0, 0.0, 1.0]):
            raise InvalidInputError(f"RigidTransform.matrix: last row must be [0, 0, 0, 1], got {m[3]}")
        _frozen_array(self, "matrix", m)

    @classmethod
    def identity(cls, dst: str = "", src: str = "") -> "RigidTransform":
        return cls(np.eye(4), dst, src)

    @classmethod
    def from_rt(cls, rotation: np.ndarray, translation: np.ndarray, dst: str = "", src: str = "") -> "RigidTransform":
        """From a (3, 3) rotation and a (3,) translation: ``p_dst = R p_src + t``."""
        m = np.eye(4)
        m[:3, :3] = check_array(rotation, "rotation", shape=(3, 3), dtype="float", finite=True)
        m[:3, 3] = check_array(translation, "translation", shape=(3,), dtype=("float", "int"), finite=True)
        return cls(m, dst, src)

    @classmethod
    def from_quaternion(cls, translation: np.ndarray, quat_xyzw: np.ndarray, dst: str = "", src: str = "") -> "RigidTransform":
        """From a translation and a unit quaternion (x, y, z, w), the TUM RGB-D order."""
        q = check_array(quat_xyzw, "quat_xyzw", shape=(4,), dtype="float", finite=True)
        n = np.linalg.norm(q)
        if not 0.5 < n < 2.0:
            raise InvalidInputError(f"quat_xyzw: expected a unit quaternion, got norm {n}")
        t = check_array(translation, "translation", shape=(3,), dtype="float", finite=True)
        return cls.from_rt(Rotation.from_quat(q / n).as_matrix(), t, dst, src)

    @property
    def rotation(self) -> np.ndarray:
        return self.matrix[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        return self.matrix[:3, 3]

    def quaternion_xyzw(self) -> np.ndarray:
        """(4,) unit quaternion (x, y, z, w) with w ≥ 0."""
        q = Rotation.from_matrix(self.rotation).as_quat()
        return -q if q[3] < 0 else q

    def inverse(self) -> "RigidTransform":
        m = np.eye(4)
        r = self.rotation
        m[:3, :3] = r.T
        m[:3, 3] = -r.T @ self.translation
        return RigidTransform(m, self.src, self.dst)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform (..., 3) points; the result has the input's float dtype (float64 for ints, float32
        for float16). A point with NaN or infinity maps to non-finite values in its own row only."""
        p = check_array(points, "points", shape=("*", 3), dtype=("float", "int"))
        dtype = p.dtype if p.dtype.kind == "f" else np.float64
        # One (N, 3) @ (3, 3) product, not a stack of per-row ones: half the time for images of points.
        out = p.reshape(-1, 3) @ self.rotation.T.astype(dtype) + self.translation.astype(dtype)
        return out.astype(dtype, copy=False).reshape(p.shape)

    def rotate(self, vectors: np.ndarray) -> np.ndarray:
        """Rotate (..., 3) direction vectors (no translation); non-finite vectors stay in their own row."""
        v = check_array(vectors, "vectors", shape=("*", 3), dtype=("float", "int"))
        dtype = v.dtype if v.dtype.kind == "f" else np.float64
        return (v.reshape(-1, 3) @ self.rotation.T.astype(dtype)).astype(dtype, copy=False).reshape(v.shape)

    def __rmatmul__(self, other: object) -> "RigidTransform":
        raise DTypeError(f"left operand of @: expected a RigidTransform, got {type(other).__name__}")

    def __matmul__(self, other: "RigidTransform") -> "RigidTransform":
        if not isinstance(other, RigidTransform):
            raise DTypeError(f"right operand of @: expected a RigidTransform, got {type(other).__name__}")
        if self.src and other.dst and self.src != other.dst:
            raise FrameError(
                f"right operand of @: expected T_{self.src}_from_*, got T_{other.dst}_from_{other.src} "
                f"(cannot compose T_{self.dst}_from_{self.src} @ T_{other.dst}_from_{other.src}: "
                f"frames {self.src!r} and {other.dst!r} differ)"
            )
        m = self.matrix @ other.matrix
        # Re-orthonormalise so long chains do not drift past the validation tolerance.
        u, _, vt = np.linalg.svd(m[:3, :3])
        m[:3, :3] = u @ vt
        return RigidTransform(m, self.dst, other.src)


@dataclass(frozen=True, eq=False)
class DepthPacket(_ArrayEq):
    """One point cloud from the ToF depth sensor.

    Attributes:
        timestamp_ns: capture time, integer nanoseconds.
        points_m: (N, 3) float32 points in the depth sensor frame (OpenCV axes), metres. N may be 0.
            Points with NaN or infinity are kept as the sensor gave them: the ingest drops them
            (:func:`rgbd_envmap.ingest.tango.depth_image_from_points`) and the session log counts them.
        confidence: (N,) float32 in [0, 1]; the paper treats < 0.7 as unknown.
        T_world_from_depth: the depth sensor's pose at capture; named frames must be
            ``("world", "depth")`` (:class:`FrameError` otherwise).
    """

    timestamp_ns: int
    points_m: np.ndarray
    confidence: np.ndarray
    T_world_from_depth: RigidTransform

    def __post_init__(self) -> None:
        object.__setattr__(self, "timestamp_ns", _timestamp(self.timestamp_ns, "timestamp_ns"))
        pts = check_array(self.points_m, "points_m", shape=("N", 3), dtype=("float", "int"))
        conf = check_array(self.confidence, "confidence", dtype=("float", "int"))
        if conf.shape != (pts.shape[0],):
            raise ShapeError(f"confidence: expected shape ({pts.shape[0]},) (one per row of points_m), got {conf.shape}")
        check_range(conf, "confidence", 0.0, 1.0)
        _frozen_array(self, "points_m", pts.astype(np.float32))
        _frozen_array(self, "confidence", conf.astype(np.float32))
        check_transform(self.T_world_from_depth, "T_world_from_depth", "world", "depth")

    @property
    def kind(self) -> str:
        return "depth"


@dataclass(frozen=True, eq=False)
class ColourPacket(_ArrayEq):
    """One colour image as the camera delivers it.

    Attributes:
        timestamp_ns: capture time, integer nanoseconds.
        nv21: (H * 3 // 2, W) uint8 Y'UV420sp buffer (Y plane, then interleaved V, U at half resolution).
        T_world_from_colour: the colour camera's pose at capture; named frames must be
            ``("world", "colour")`` (:class:`FrameError` otherwise).
        exposure_s: the frame's exposure time in seconds, or None where the camera does not say
            (older logs); with ``iso`` it gives the frame's exposure (HDR capture, docs/design/hdr.md).
        iso: the frame's sensitivity (ISO), or None.
        bracketed: a frame of an exposure bracket, taken off the auto-exposure for HDR capture: it
            goes into the map but is neither composited nor shown.
        white_balance: (R, G, B) the per-channel gains the camera's white balance applied to the
            frame (what Android reports as its colour-correction gains), or None where the camera does
            not say. With the exposure, the frame's gains relative to another frame's are known
            (``capture.known_white_balance``, docs/design/colour_correction.md).
    """

    timestamp_ns: int
    nv21: np.ndarray
    T_world_from_colour: RigidTransform
    exposure_s: float | None = None
    iso: float | None = None
    bracketed: bool = False
    white_balance: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "timestamp_ns", _timestamp(self.timestamp_ns, "timestamp_ns"))
        buf = check_array(self.nv21, "nv21", shape=("R", "W"), dtype=np.uint8)
        rows, width = buf.shape
        if rows == 0 or width == 0 or rows % 3 or width % 2 or (rows * 2 // 3) % 2:
            raise InvalidInputError(
                f"nv21: expected shape (H*3/2, W) with even H, W > 0, got {buf.shape}"
            )
        _frozen_array(self, "nv21", buf)
        check_transform(self.T_world_from_colour, "T_world_from_colour", "world", "colour")
        for name in ("exposure_s", "iso"):
            value = check_number(getattr(self, name), name, low=0.0, low_open=True, optional=True)
            object.__setattr__(self, name, None if value is None else float(value))
        object.__setattr__(self, "bracketed", check_flag(self.bracketed, "bracketed"))
        if self.white_balance is not None:
            wb = check_array(self.white_balance, "white_balance", shape=(3,), dtype=("float", "int"), finite=True)
            if not (wb > 0).all():
                raise RangeError(f"white_balance: expected three gains > 0, got {wb.tolist()}")
            object.__setattr__(self, "white_balance", tuple(float(w) for w in wb))

    @property
    def exposure(self) -> float | None:
        """Exposure time × ISO (the sensor's linear gain up to a constant), or None when either is unknown."""
        return None if self.exposure_s is None or self.iso is None else self.exposure_s * self.iso

    @property
    def kind(self) -> str:
        return "colour"

    @property
    def height(self) -> int:
        return self.nv21.shape[0] * 2 // 3

    @property
    def width(self) -> int:
        return self.nv21.shape[1]


SensorPacket = Union[DepthPacket, ColourPacket]


@dataclass(frozen=True)
class Calibration:
    """Everything fixed about a device: both cameras' intrinsics and the depth-to-colour extrinsics.

    Attributes:
        sensor: ``"tango"`` (point clouds + NV21) or ``"kinect"`` (depth images + RGB).
        depth: intrinsics of the depth sensor (also the RGB-D frame's intrinsics).
        colour: intrinsics of the colour camera.
        T_colour_from_depth: maps points from the depth sensor frame into the colour camera frame.
        depth_rate_hz, colour_rate_hz: nominal packet rates.
    """

    sensor: str
    depth: Intrinsics
    colour: Intrinsics
    T_colour_from_depth: RigidTransform
    depth_rate_hz: float = 5.0
    colour_rate_hz: float = 30.0

    def __post_init__(self) -> None:
        if not isinstance(self.sensor, str) or self.sensor not in ("tango", "kinect"):
            raise InvalidInputError(f"Calibration.sensor: expected 'tango' or 'kinect', got {self.sensor!r}")
        check_instance(self.depth, Intrinsics, "Calibration.depth")
        check_instance(self.colour, Intrinsics, "Calibration.colour")
        check_transform(self.T_colour_from_depth, "Calibration.T_colour_from_depth", "colour", "depth")
        for name in ("depth_rate_hz", "colour_rate_hz"):
            object.__setattr__(self, name, check_number(getattr(self, name), f"Calibration.{name}", low=0.0, low_open=True))

    def to_dict(self) -> dict:
        return {
            "sensor": self.sensor,
            "depth": self.depth.to_dict(),
            "colour": self.colour.to_dict(),
            "T_colour_from_depth": self.T_colour_from_depth.matrix.tolist(),
            "depth_rate_hz": self.depth_rate_hz,
            "colour_rate_hz": self.colour_rate_hz,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Calibration":
        """The calibration :meth:`to_dict` wrote; a missing key is an :class:`InvalidInputError` naming
        it (and the keys found)."""
        check_instance(d, Mapping, "d")
        matrix = check_array(_mapping_get(d, "T_colour_from_depth", "d"), "d['T_colour_from_depth']", shape=(4, 4), dtype=("float", "int"))
        return cls(
            sensor=_mapping_get(d, "sensor", "d"),
            depth=Intrinsics.from_dict(_mapping_get(d, "depth", "d")),
            colour=Intrinsics.from_dict(_mapping_get(d, "colour", "d")),
            T_colour_from_depth=RigidTransform(matrix.astype(np.float64), "colour", "depth"),
            depth_rate_hz=d.get("depth_rate_hz", 5.0),
            colour_rate_hz=d.get("colour_rate_hz", 30.0),
        )


@dataclass(frozen=True, eq=False)
class RGBDFrame(_ArrayEq):
    """An RGB-D frame in the depth sensor's image grid.

    Attributes:
        rgb: (H, W, 3) float32 linear RGB in the current camera's colour space. Kept as given, as ``depth_m``.
        depth_m: (H, W) float32 z-depth in metres; meaningful only where ``known``. Values are kept
            as given, NaN included: the denoiser and the map update skip a non-finite depth at a
            known pixel, :func:`rgbd_envmap.depth.fill_holes` refuses it (``NonFiniteError``).
        known: (H, W) bool, True where depth_m holds a measurement or an estimate.
        T_world_from_cam: pose of the frame's camera (named frames: into ``"world"``).
        intrinsics: the frame's (depth sensor) intrinsics.
        timestamp_ns: capture time of the depth data.
        clipped: (H, W) bool, pixels whose colour has a channel at the camera's clip level (HDR
            capture: the map keeps such a colour as a lower bound only), or None (none known).
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    known: np.ndarray
    T_world_from_cam: RigidTransform
    intrinsics: Intrinsics
    timestamp_ns: int
    clipped: np.ndarray | None = None

    def __post_init__(self) -> None:
        check_instance(self.intrinsics, Intrinsics, "intrinsics")
        check_transform(self.T_world_from_cam, "T_world_from_cam", "world")
        h, w = self.intrinsics.height, self.intrinsics.width
        rgb = check_array(self.rgb, "rgb", shape=(h, w, 3), dtype="float")
        depth = check_array(self.depth_m, "depth_m", shape=(h, w), dtype="float")
        known = check_array(self.known, "known", shape=(h, w), dtype="bool")
        _frozen_array(self, "rgb", rgb.astype(np.float32))
        _frozen_array(self, "depth_m", depth.astype(np.float32))
        _frozen_array(self, "known", known)
        object.__setattr__(self, "timestamp_ns", _timestamp(self.timestamp_ns, "timestamp_ns"))
        if self.clipped is not None:
            _frozen_array(self, "clipped", check_array(self.clipped, "clipped", shape=(h, w), dtype="bool"))

    def with_depth(self, depth_m: np.ndarray) -> "RGBDFrame":
        """This frame with ``depth_m`` ((H, W) float) as its depth; colours, mask, pose and time
        shared with this frame (they are read-only). The depth is stored as a read-only float32 copy,
        or shared when it already is read-only float32. Building the frame through the constructor
        checks and copies all three arrays (0.05 ms for 224×172, a third of the 3×3 denoising stage).
        """
        depth = check_array(depth_m, "depth_m", shape=self.depth_m.shape, dtype="float")
        if depth.dtype != np.float32 or depth.flags.writeable:
            depth = depth.astype(np.float32)
            depth.setflags(write=False)
        out = copy.copy(self)  # a shallow copy: __post_init__ does not run again
        object.__setattr__(out, "depth_m", depth)
        return out

