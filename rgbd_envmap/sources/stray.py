"""Phone LiDAR captures in the Stray Scanner layout (iPhone / iPad with ARKit depth): the modern Tango.

A capture is one folder (the layout of the Stray Scanner app's ``docs/format.md``)::

    rgb.mp4                 the colour video (HEVC or H.264; 1920×1440 on current iPhones)
    depth/NNNNNN.png        16-bit z-depth in millimetres, 256×192, registered to the colour image's
                            field of view (the same optical frame); 0 = no depth
    confidence/NNNNNN.png   8-bit ARKit confidence of each depth pixel: 0 low, 1 medium, 2 high
    camera_matrix.csv       the colour camera's 3×3 intrinsics at the video's resolution, rows comma-separated
    odometry.csv            header ``timestamp, frame, x, y, z, qx, qy, qz, qw``, one row per frame:
                            timestamp in seconds, the frame number, and ``T_arkit_from_cam`` (position in
                            metres, unit quaternion x, y, z, w) with OpenCV camera axes (x right, y down,
                            z forward) in ARKit's world, whose +y is up
    imu.csv                 (not used)

``NNNNNN`` is the frame number, the index of the frame in the video counted from 0, which is also
odometry's ``frame`` column; frames are matched by it, never by time. Stray Scanner writes a depth
image per video frame; a capture may hold depth for only some frames.

How it becomes the pipeline's packets (:func:`read_stray_capture`, :meth:`StrayCapture.packets`), so
that :class:`rgbd_envmap.pipeline.Pipeline` runs the mobile (Tango) path on it unchanged:

- **World axes.** ARKit's world is y-up; ours is z-up. ``(x, y, z)_ours = (x, −z, y)_ARKit``, the
  rotation :data:`T_WORLD_FROM_ARKIT` (det +1), applied on the left: ``T_world_from_cam =
  A · T_arkit_from_cam`` (:func:`pose_from_arkit`), which turns positions and rotations alike and
  keeps the map's azimuth fixed to ARKit's (its −z, the session's first heading, is our +y). The camera
  axes are OpenCV already (Stray turns ARKit's camera by 180° about x before writing).
- **Calibration** (sensor ``"tango"``): colour intrinsics = ``camera_matrix.csv`` at the video's coded
  size (scaled to ``colour_size`` when the frames are decoded smaller); depth intrinsics = the same
  matrix scaled to the depth PNGs' size with :meth:`Intrinsics.scaled`, which keeps the pixel-centre
  convention (``cx' = (cx + 0.5)·s − 0.5``: the depth image spans the colour image's field of view edge
  to edge); no distortion (the layout has none); ``T_colour_from_depth`` the identity.
- **Depth** (:func:`depth_packet_from_image`): every pixel with a depth becomes a point ``z · ray(u, v)``
  in the depth camera frame, with the confidence :data:`CONFIDENCE_VALUES` of its level: 0 → 0.0,
  1 → 0.5, 2 → 1.0. The ingest's rule "confidence ≥ 0.7" (``ingest.confidence_threshold``) therefore
  keeps high-confidence pixels only; ``--set ingest.confidence_threshold=0.5`` keeps medium ones too.
  A missing ``confidence/`` folder counts every pixel as high. Depth packets are fed at
  ``depth_rate_hz`` (default 5 Hz, the Tango ToF's rate the pipeline's stages were built for): a frame's
  depth is taken when at least one period minus half the median interval between depth images has
  passed since the last one taken (None: every depth image).
- **Colour**: the video is decoded frame by frame by the ffmpeg that imageio-ffmpeg ships, piped as raw
  rgb24 (swscale's ``accurate_rnd+full_chroma_int``: no rounding bias against OpenCV's BT.601 decode),
  without auto-rotation (the intrinsics are the sensor's orientation) and without frame-rate conversion
  (``-fps_mode passthrough``: no frame duplicated or dropped), then encoded as NV21
  (:func:`rgbd_envmap.colour.encode_nv21`).
- **Time and order**: odometry's seconds (ARKit's clock) are parsed as decimal text into integer
  nanoseconds. Packets come by frame number: a frame's depth packet (when taken) and then its colour
  packet, both with the frame's timestamp and pose, so the pipeline pairs them with zero lag.

:class:`StrayWriter` writes the layout (the simulator's phone capture uses it): H.264 through
imageio-ffmpeg from NV21 buffers (libx264, 4:2:0, BT.601 limited range as OpenCV's NV21; ``crf=0`` is
lossless), 16-bit millimetre depth and 8-bit confidence PNGs, ``camera_matrix.csv`` and
``odometry.csv`` in ARKit's conventions (:func:`pose_to_arkit`, the inverse axis change).

Errors: a problem with a file raises :class:`~rgbd_envmap.errors.LogFormatError` naming the file (and
the line, for text files): missing files, a malformed camera matrix, a wrong odometry header or field,
a non-increasing timestamp, a duplicate frame, a NaN or non-unit quaternion, an unreadable or truncated
PNG, a PNG of the wrong dtype or size, a confidence level above 2, an undecodable video.

References:
    Stray Robots, Stray Scanner data specification (github.com/strayrobots/scanner, docs/format.md).
    Apple, ARKit ``ARDepthData`` (depth map, confidence map ``ARConfidenceLevel`` low / medium / high).
"""

from __future__ import annotations

import math
import shutil
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path

import cv2
import numpy as np

from rgbd_envmap.checks import check_array, check_number
from rgbd_envmap.colour.nv21 import encode_nv21
from rgbd_envmap.errors import InvalidInputError, LogFormatError, RgbdEnvmapError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Calibration, ColourPacket, DepthPacket, Intrinsics, RigidTransform, SensorPacket

__all__ = [
    "T_WORLD_FROM_ARKIT",
    "CONFIDENCE_VALUES",
    "DEPTH_UNITS_PER_M",
    "DEFAULT_DEPTH_SIZE",
    "ODOMETRY_HEADER",
    "StrayFrame",
    "StrayCapture",
    "StrayWriter",
    "is_stray_capture",
    "read_stray_capture",
    "read_camera_matrix",
    "read_odometry",
    "pose_from_arkit",
    "pose_to_arkit",
    "confidence_from_levels",
    "depth_packet_from_image",
]

#: ``(x, y, z)_ours = (x, −z, y)_ARKit``: ARKit's y-up world → ours (z up), a rotation (det +1).
T_WORLD_FROM_ARKIT = RigidTransform(
    np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]), "world", "arkit")
#: DepthPacket confidence of ARKit's levels 0 (low), 1 (medium), 2 (high). With the ingest's default
#: threshold 0.7 only level 2 counts; a threshold of 0.5 admits level 1 as well.
CONFIDENCE_VALUES = (0.0, 0.5, 1.0)
#: depth PNG units per metre (millimetres).
DEPTH_UNITS_PER_M = 1000.0
#: (width, height) of ARKit's depth maps, for a capture without depth images.
DEFAULT_DEPTH_SIZE = (256, 192)
ODOMETRY_HEADER = ("timestamp", "frame", "x", "y", "z", "qx", "qy", "qz", "qw")
#: largest accepted | |q| − 1 | of an odometry quaternion (Swift prints floats to ~7 digits).
QUATERNION_NORM_TOL = 1e-3
_FRAMES = ("world", "colour")
_OWNED = ("rgb.mp4", "depth", "confidence", "camera_matrix.csv", "odometry.csv")
_SWS_FLAGS = "accurate_rnd+full_chroma_int"


def pose_from_arkit(T_arkit_from_cam: np.ndarray | RigidTransform, src: str = "colour") -> RigidTransform:
    """``T_world_from_cam`` (our z-up world, frames ``("world", src)``) of an odometry pose
    ``T_arkit_from_cam`` (4×4, ARKit's y-up world, OpenCV camera axes): ``A · T``."""
    m = T_arkit_from_cam.matrix if isinstance(T_arkit_from_cam, RigidTransform) else np.asarray(T_arkit_from_cam, np.float64)
    return RigidTransform(T_WORLD_FROM_ARKIT.matrix @ RigidTransform(m).matrix, "world", src)


def pose_to_arkit(T_world_from_cam: RigidTransform) -> RigidTransform:
    """The inverse of :func:`pose_from_arkit`: ``Aᵀ · T`` (frames ``("arkit", src)``)."""
    if not isinstance(T_world_from_cam, RigidTransform):
        raise InvalidInputError(f"T_world_from_cam: expected a RigidTransform, got {type(T_world_from_cam).__name__}")
    return RigidTransform(T_WORLD_FROM_ARKIT.matrix.T @ T_world_from_cam.matrix, "arkit", T_world_from_cam.src)


def confidence_from_levels(levels: np.ndarray) -> np.ndarray:
    """(…) uint8 ARKit confidence levels 0 / 1 / 2 → (…) float32 :data:`CONFIDENCE_VALUES`."""
    lv = check_array(levels, "levels", dtype=("int", "uint"))
    if lv.size and (lv.min() < 0 or lv.max() > 2):
        raise InvalidInputError(f"levels: expected ARKit confidence levels 0, 1 or 2, got values in [{lv.min()}, {lv.max()}]")
    return np.asarray(CONFIDENCE_VALUES, np.float32)[lv.astype(np.intp)]


def depth_packet_from_image(timestamp_ns: int, depth_m: np.ndarray, known: np.ndarray, confidence: np.ndarray,
                            intrinsics: Intrinsics, T_world_from_depth: RigidTransform) -> DepthPacket:
    """A depth image unprojected into the point cloud of a :class:`DepthPacket`.

    Args:
        depth_m: (H, W) float z-depth in metres, meaningful where ``known``.
        known: (H, W) bool, a depth was measured.
        confidence: (H, W) float in [0, 1], each pixel's confidence (e.g. :func:`confidence_from_levels`).
        intrinsics: the depth image's (H, W must match); its distortion is honoured.
        T_world_from_depth: the depth camera's pose.

    Returns:
        A packet whose points (``depth_m · ray(u, v)``, float32, depth camera frame, OpenCV axes) are
        the known pixels in row-major order, with their confidences.
    """
    h, w = intrinsics.shape
    depth = check_array(depth_m, "depth_m", shape=(h, w), dtype="float")
    mask = check_array(known, "known", shape=(h, w), dtype="bool")
    conf = check_array(confidence, "confidence", shape=(h, w), dtype="float")
    z = depth[mask].astype(np.float64)
    if z.size and not (np.isfinite(z).all() and (z > 0).all()):
        raise InvalidInputError("depth_m: expected finite depths > 0 where known")
    points = (pixel_rays(intrinsics)[mask] * z[:, None]).astype(np.float32)
    return DepthPacket(timestamp_ns, points, conf[mask].astype(np.float32),
                       RigidTransform(T_world_from_depth.matrix, "world", "depth"))


# --- reading ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StrayFrame:
    """One row of ``odometry.csv``.

    Attributes:
        frame: the frame number (video frame index; the name of its depth / confidence PNGs).
        timestamp_ns: its time, integer nanoseconds (ARKit's clock).
        T_world_from_cam: the colour camera's pose in our z-up world (frames ``("world", "colour")``).
        line: the row's 1-based line in ``odometry.csv``.
    """

    frame: int
    timestamp_ns: int
    T_world_from_cam: RigidTransform
    line: int


def is_stray_capture(path: Path) -> bool:
    """True for a folder in the Stray Scanner layout (``odometry.csv``, ``camera_matrix.csv`` and ``rgb.mp4``)."""
    path = Path(path)
    return all((path / name).is_file() for name in ("odometry.csv", "camera_matrix.csv", "rgb.mp4"))


def _read_text(path: Path) -> str:
    try:
        return path.read_bytes().decode("utf-8", "replace")
    except OSError as exc:
        why = "missing file" if isinstance(exc, FileNotFoundError) else str(exc)
        raise LogFormatError(f"{path}: {why}") from None


def read_camera_matrix(path: Path) -> np.ndarray:
    """(3, 3) float64 intrinsics of ``camera_matrix.csv`` (three rows of three comma-separated numbers,
    ``fx 0 cx / 0 fy cy / 0 0 1``); anything else raises :class:`LogFormatError` naming the line."""
    path = Path(path)
    rows = []
    for lineno, line in enumerate(_read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(",")]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise LogFormatError(f"{path}, line {lineno}: expected three comma-separated numbers, got {line.strip()!r}") from None
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise LogFormatError(f"{path}, line {lineno}: expected three finite comma-separated numbers, got {line.strip()!r}")
        rows.append(values)
    if len(rows) != 3:
        raise LogFormatError(f"{path}: expected a 3×3 matrix (three rows), got {len(rows)} rows")
    K = np.array(rows, np.float64)
    if K[1, 0] or K[2, 0] or K[2, 1] or K[0, 1] or K[2, 2] != 1.0:
        raise LogFormatError(f"{path}: expected a pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {K.tolist()}")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise LogFormatError(f"{path}: expected focal lengths > 0, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K


def _parse_seconds(text: str) -> int:
    """Decimal seconds (any number of digits) → integer nanoseconds, rounded half to even."""
    try:
        d = Decimal(text)
    except InvalidOperation:
        raise ValueError(f"malformed timestamp {text!r}") from None
    if not d.is_finite() or d < 0:
        raise ValueError(f"timestamp {text!r}: expected a finite number of seconds ≥ 0")
    ns = int((d * 10**9).to_integral_value())
    if ns >= 2**63:
        raise ValueError(f"timestamp {text!r} does not fit in int64 nanoseconds")
    return ns


def read_odometry(path: Path) -> list[StrayFrame]:
    """The rows of ``odometry.csv``, sorted by frame number, poses in our world (:func:`pose_from_arkit`).

    The header names the columns (spaces around the commas are ignored; columns beyond
    :data:`ODOMETRY_HEADER` are ignored). Frame numbers must be distinct and timestamps must increase
    with them; quaternions must be unit (within 1e-3; normalised) and every value finite."""
    path = Path(path)
    lines = _read_text(path).splitlines()
    header_at = next((i for i, line in enumerate(lines) if line.strip()), None)
    if header_at is None:
        raise LogFormatError(f"{path}: empty file (expected the header {', '.join(ODOMETRY_HEADER)})")
    names = [f.strip() for f in lines[header_at].split(",")]
    missing = [n for n in ODOMETRY_HEADER if n not in names]
    if missing:
        raise LogFormatError(f"{path}, line {header_at + 1}: header lacks {missing}; expected {', '.join(ODOMETRY_HEADER)}, "
                             f"got {lines[header_at].strip()!r}")
    col = {n: names.index(n) for n in ODOMETRY_HEADER}
    rows: list[StrayFrame] = []
    for lineno, line in enumerate(lines[header_at + 1:], start=header_at + 2):
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != len(names):
            raise LogFormatError(f"{path}, line {lineno}: expected {len(names)} fields, got {len(fields)}: {line.strip()!r}")
        try:
            ns = _parse_seconds(fields[col["timestamp"]])
            frame_text = fields[col["frame"]]
            if not frame_text.isdigit():
                raise ValueError(f"frame: expected a non-negative integer, got {frame_text!r}")
            frame = int(frame_text)
            t = np.array([float(fields[col[k]]) for k in ("x", "y", "z")])
            q = np.array([float(fields[col[k]]) for k in ("qx", "qy", "qz", "qw")])
        except ValueError as exc:
            raise LogFormatError(f"{path}, line {lineno}: {exc}") from None
        if not (np.isfinite(t).all() and np.isfinite(q).all()):
            raise LogFormatError(f"{path}, line {lineno}: NaN or infinite pose value")
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > QUATERNION_NORM_TOL:
            raise LogFormatError(f"{path}, line {lineno}: quaternion norm {norm:.6g} is not 1 (tolerance {QUATERNION_NORM_TOL})")
        try:
            T = RigidTransform.from_quaternion(t, q / norm)
        except RgbdEnvmapError as exc:
            raise LogFormatError(f"{path}, line {lineno}: invalid pose ({exc})") from None
        rows.append(StrayFrame(frame, ns, pose_from_arkit(T), lineno))
    rows.sort(key=lambda r: r.frame)
    for a, b in zip(rows, rows[1:]):
        if a.frame == b.frame:
            raise LogFormatError(f"{path}, line {b.line}: frame {b.frame} appears twice (also line {a.line})")
        if b.timestamp_ns <= a.timestamp_ns:
            raise LogFormatError(f"{path}, line {b.line}: timestamp of frame {b.frame} does not increase over frame {a.frame} "
                                 f"(line {a.line})")
    return rows


def _read_png(path: Path) -> np.ndarray:
    try:
        data = path.read_bytes()
    except OSError as exc:
        why = "missing file" if isinstance(exc, FileNotFoundError) else str(exc)
        raise LogFormatError(f"{path}: {why}") from None
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise LogFormatError(f"{path}: not a PNG file")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)  # libpng rejects truncation and CRC errors
    if img is None:
        raise LogFormatError(f"{path}: unreadable, truncated or corrupt PNG")
    return img


def _png_frames(folder: Path) -> set[int]:
    if not folder.is_dir():
        return set()
    return {int(p.stem) for p in folder.glob("*.png") if p.stem.isdigit()}


def _video_meta(path: Path) -> dict:
    import imageio_ffmpeg

    if not path.is_file():
        raise LogFormatError(f"{path}: missing file")
    try:
        gen = imageio_ffmpeg.read_frames(str(path), input_params=["-noautorotate"])
        try:
            meta = next(gen)
        finally:
            gen.close()
    except (OSError, RuntimeError, StopIteration, KeyError, ValueError) as exc:
        raise LogFormatError(f"{path}: unreadable video ({type(exc).__name__}: {str(exc).strip()[:300]})") from None
    size = meta.get("source_size") or meta.get("size")
    if not size or size[0] <= 0 or size[1] <= 0:
        raise LogFormatError(f"{path}: no video stream with a frame size")
    return meta


def _median_rate_hz(timestamps_ns: list[int], default: float) -> float:
    if len(timestamps_ns) < 2:
        return default
    dt = float(np.median(np.diff(np.asarray(timestamps_ns, np.int64))))
    return round(1e9 / dt, 3) if dt > 0 else default


class StrayCapture:
    """A Stray Scanner capture opened for reading (:func:`read_stray_capture`); images are read lazily.

    Attributes:
        root: the capture folder.
        calibration: ``"tango"`` calibration (colour intrinsics at the decode size, depth intrinsics at
            the depth PNGs' size, identity extrinsics, the rates the packets come at).
        camera_matrix: (3, 3) ``camera_matrix.csv`` (the video's coded size ``video_size``).
        video_size: (width, height) of the video as coded; ``colour_size``: as decoded.
        frames: the odometry rows (:class:`StrayFrame`) by frame number.
        depth_frames: the frame numbers whose depth is fed, in order (chosen at ``depth_rate_hz``).
        has_confidence: the ``confidence/`` folder exists (else every depth pixel counts as high).
        skipped: counts of what is not fed: ``depth_without_pose`` (depth PNGs of frames odometry lacks),
            ``depth_not_taken`` (depth images between the ``depth_rate_hz`` picks), and after
            :meth:`packets` ran, ``colour_without_pose`` (video frames past or between odometry's rows)
            and ``pose_without_colour`` (rows whose video frame does not exist).
    """

    def __init__(self, root: Path, calibration: Calibration, camera_matrix: np.ndarray, video_size: tuple[int, int],
                 colour_size: tuple[int, int], frames: list[StrayFrame], depth_frames: list[int], has_confidence: bool,
                 skipped: dict[str, int], depth_rate_hz: float | None) -> None:
        """Use :func:`read_stray_capture`."""
        self.root, self.calibration, self.camera_matrix = root, calibration, camera_matrix
        self.video_size, self.colour_size = video_size, colour_size
        self.frames, self.depth_frames, self.has_confidence = frames, depth_frames, has_confidence
        self.skipped, self.depth_rate_hz = Counter(skipped), depth_rate_hz
        self._by_frame = {f.frame: f for f in frames}

    def __len__(self) -> int:
        """The number of packets :meth:`packets` yields when every file is readable (for progress bars)."""
        return len(self.frames) + len(self.depth_frames)

    def frame(self, number: int) -> StrayFrame:
        """The odometry row of frame ``number`` (KeyError if it has none)."""
        return self._by_frame[number]

    def depth_path(self, frame: int) -> Path:
        return self.root / "depth" / f"{frame:06d}.png"

    def confidence_path(self, frame: int) -> Path:
        return self.root / "confidence" / f"{frame:06d}.png"

    def read_depth_image(self, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(depth_m (H, W) float32 z-depth, known (H, W) bool, levels (H, W) uint8 0 / 1 / 2) of frame
        ``frame``; :class:`LogFormatError` names the file when one is missing or malformed."""
        h, w = self.calibration.depth.shape
        path = self.depth_path(frame)
        mm = _read_png(path)
        if mm.dtype != np.uint16 or mm.ndim != 2:
            raise LogFormatError(f"{path}: expected a single-channel 16-bit depth PNG, got dtype {mm.dtype} with shape {mm.shape}")
        if mm.shape != (h, w):
            raise LogFormatError(f"{path}: expected {w}×{h} like the capture's other depth images, got {mm.shape[1]}×{mm.shape[0]}")
        if self.has_confidence:
            cpath = self.confidence_path(frame)
            levels = _read_png(cpath)
            if levels.dtype != np.uint8 or levels.ndim != 2 or levels.shape != (h, w):
                raise LogFormatError(f"{cpath}: expected a single-channel 8-bit {w}×{h} confidence PNG, "
                                     f"got dtype {levels.dtype} with shape {levels.shape}")
            if levels.max(initial=0) > 2:
                raise LogFormatError(f"{cpath}: expected confidence levels 0, 1 or 2, got up to {levels.max()}")
        else:
            levels = np.full((h, w), 2, np.uint8)
        known = mm > 0
        return (mm / DEPTH_UNITS_PER_M).astype(np.float32), known, levels

    def read_depth(self, frame: int) -> DepthPacket:
        """Frame ``frame``'s depth as a :class:`DepthPacket` at its odometry time and pose."""
        row = self._by_frame[frame]
        depth_m, known, levels = self.read_depth_image(frame)
        return depth_packet_from_image(row.timestamp_ns, depth_m, known, confidence_from_levels(levels),
                                       self.calibration.depth, row.T_world_from_cam)

    def colour_images(self) -> Iterator[tuple[int, np.ndarray]]:
        """(frame number, (H, W, 3) uint8 sRGB at ``colour_size``) of every video frame in order.

        Raises:
            LogFormatError: naming ``rgb.mp4`` when ffmpeg cannot decode it (a video cut short ends
                with the error after its last complete frame).
        """
        import imageio_ffmpeg

        w, h = self.colour_size
        output = ["-fps_mode", "passthrough", "-sws_flags", _SWS_FLAGS]
        if (w, h) != tuple(self.video_size):
            output += ["-vf", f"scale={w}:{h}:flags=area+accurate_rnd+full_chroma_int"]
        path = self.root / "rgb.mp4"
        gen = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24", input_params=["-noautorotate"], output_params=output)
        index = 0
        try:
            try:
                meta = next(gen)
            except (OSError, RuntimeError, StopIteration) as exc:
                raise LogFormatError(f"{path}: unreadable video ({type(exc).__name__}: {str(exc).strip()[:300]})") from None
            if tuple(meta["size"]) != (w, h):
                raise LogFormatError(f"{path}: ffmpeg delivers {meta['size']} frames, expected {w}×{h}")
            while True:
                try:
                    data = next(gen)
                except StopIteration:
                    return
                except (OSError, RuntimeError) as exc:
                    raise LogFormatError(f"{path}: frame {index} could not be decoded "
                                         f"({type(exc).__name__}: {str(exc).strip()[:300]})") from None
                yield index, np.frombuffer(data, np.uint8).reshape(h, w, 3)
                index += 1
        finally:
            gen.close()

    def packets(self, on_error: Callable[[str, LogFormatError], None] | None = None
                ) -> Iterator[tuple[SensorPacket, StrayFrame]]:
        """(packet, its odometry row) in delivery order: per frame number, its depth packet (if the frame
        is one of :attr:`depth_frames`) and then its colour packet.

        ``on_error(kind, error)`` is called for an unreadable depth image (kind ``"depth"``; the frame's
        colour still comes) or an undecodable video (``"colour"``; the stream ends there); without it
        the error propagates. Counts of frames without a pose or without video go to :attr:`skipped`.
        """
        depth = set(self.depth_frames)
        seen: set[int] = set()
        self.skipped["colour_without_pose"] = self.skipped["pose_without_colour"] = 0  # counted afresh per pass
        images = self.colour_images()
        try:
            while True:
                try:
                    index, rgb = next(images)
                except StopIteration:
                    break
                except LogFormatError as exc:
                    if on_error is None:
                        raise
                    on_error("colour", exc)
                    break
                row = self._by_frame.get(index)
                if row is None:
                    self.skipped["colour_without_pose"] += 1
                    continue
                seen.add(index)
                if index in depth:
                    try:
                        packet = self.read_depth(index)
                    except LogFormatError as exc:
                        if on_error is None:
                            raise
                        on_error("depth", exc)
                    else:
                        yield packet, row
                yield ColourPacket(row.timestamp_ns, encode_nv21(rgb), row.T_world_from_cam), row
        finally:
            images.close()  # stops ffmpeg when the caller stops early or an error ends the stream
        missing = len(self.frames) - len(seen)
        if missing:
            self.skipped["pose_without_colour"] += missing


def _pick_depth(rows: list[StrayFrame], rate_hz: float | None) -> list[int]:
    """Frame numbers of ``rows`` (those with depth, by frame) taken at ``rate_hz``: a frame when at least
    one period minus half the median interval between depth images has passed since the last one taken."""
    if rate_hz is None or len(rows) < 2:
        return [r.frame for r in rows]
    stamps = np.array([r.timestamp_ns for r in rows], np.int64)
    slack = 0.5 * float(np.median(np.diff(stamps)))
    period = 1e9 / rate_hz
    out, last = [], None
    for r in rows:
        if last is None or r.timestamp_ns - last >= period - slack:
            out.append(r.frame)
            last = r.timestamp_ns
    return out


def read_stray_capture(root: Path, *, depth_rate_hz: float | None = 5.0,
                       colour_size: tuple[int, int] | None = None) -> StrayCapture:
    """Open a capture in the Stray Scanner layout (the module docstring describes the layout and the
    conversion).

    Args:
        root: the capture folder.
        depth_rate_hz: the rate depth packets are fed at (> 0; default 5 Hz, the Tango's), or None for
            every depth image.
        colour_size: (width, height) to decode the video at (even; the intrinsics are scaled to it), or
            None for the video's own size (which must then be even: NV21).

    Raises:
        LogFormatError: a file is missing or malformed (named, with its line).
        InvalidInputError: a bad argument.
    """
    root = Path(root)
    if depth_rate_hz is not None:
        depth_rate_hz = check_number(depth_rate_hz, "depth_rate_hz", low=0.0, low_open=True)
    if not root.is_dir():
        raise LogFormatError(f"{root}: not a directory")
    K = read_camera_matrix(root / "camera_matrix.csv")
    frames = read_odometry(root / "odometry.csv")
    if not frames:
        raise LogFormatError(f"{root / 'odometry.csv'}: no frames")
    meta = _video_meta(root / "rgb.mp4")
    size = meta.get("source_size") or meta["size"]
    video_size = (int(size[0]), int(size[1]))
    vw, vh = video_size
    if not (-0.5 <= K[0, 2] <= vw - 0.5 and -0.5 <= K[1, 2] <= vh - 0.5):
        raise LogFormatError(f"{root / 'camera_matrix.csv'}: principal point ({K[0, 2]}, {K[1, 2]}) lies outside the video's "
                             f"{vw}×{vh} frame (a matrix of another resolution?)")
    if colour_size is None:
        colour_size = video_size
    cw, ch = (int(v) for v in colour_size)
    if cw <= 0 or ch <= 0 or cw % 2 or ch % 2:
        raise InvalidInputError(f"colour_size: expected an even width and height > 0 (NV21), got {cw}×{ch}"
                                + (" (the video's own size; pass an even colour_size)" if (cw, ch) == video_size else ""))
    video = Intrinsics(vw, vh, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    colour = video if (cw, ch) == video_size else video.scaled(cw, ch)

    with_depth = _png_frames(root / "depth")
    has_confidence = (root / "confidence").is_dir()
    by_frame = {f.frame for f in frames}
    rows_with_depth = [f for f in frames if f.frame in with_depth]
    taken = _pick_depth(rows_with_depth, depth_rate_hz)
    skipped = {"depth_without_pose": len(with_depth - by_frame), "depth_not_taken": len(rows_with_depth) - len(taken)}
    dw, dh = DEFAULT_DEPTH_SIZE
    if rows_with_depth:
        first = root / "depth" / f"{rows_with_depth[0].frame:06d}.png"
        img = _read_png(first)
        if img.dtype != np.uint16 or img.ndim != 2:
            raise LogFormatError(f"{first}: expected a single-channel 16-bit depth PNG, got dtype {img.dtype} with shape {img.shape}")
        dh, dw = img.shape
    colour_rate = _median_rate_hz([f.timestamp_ns for f in frames], 30.0)
    rows = {f.frame: f for f in frames}
    depth_rate = _median_rate_hz([rows[i].timestamp_ns for i in taken], depth_rate_hz or colour_rate)
    calibration = Calibration(
        sensor="tango", depth=video.scaled(dw, dh), colour=colour,
        T_colour_from_depth=RigidTransform.identity("colour", "depth"),
        depth_rate_hz=depth_rate, colour_rate_hz=colour_rate,
    )
    return StrayCapture(root, calibration, K, video_size, (cw, ch), frames, taken, has_confidence, skipped, depth_rate_hz)


# --- writing ---------------------------------------------------------------------------------------


def _format_seconds(timestamp_ns: int) -> str:
    ns = int(timestamp_ns)
    if ns < 0:
        raise InvalidInputError(f"timestamp_ns: expected >= 0, got {ns}")
    return f"{ns // 10**9}.{ns % 10**9:09d}"


class StrayWriter:
    """Writes a capture in the Stray Scanner layout, frame by frame (a context manager).

    ``rgb.mp4`` is H.264 (libx264 through imageio-ffmpeg's ffmpeg) encoded from NV21 buffers as they are
    (4:2:0, tagged BT.601 limited range, OpenCV's NV21 convention); ``crf=0`` (the default) is
    lossless, so a decoded frame differs from :func:`rgbd_envmap.colour.decode_nv21` of the buffer only
    by the two YUV → RGB conversions' rounding (≤ 1 code on average). Depth goes to 16-bit millimetre
    PNGs (rounded; 0 where unknown or beyond 65.535 m), confidence to 8-bit PNGs, poses to
    ``odometry.csv`` in ARKit's world (:func:`pose_to_arkit`) with 17 significant digits and the
    timestamp with 9 decimals, so they read back exactly (to ~1e-16).

    Args:
        root: the capture folder (created; an existing capture in it needs ``overwrite``).
        colour: the colour camera's intrinsics at the video's size (even; no distortion: the layout has
            none). ``camera_matrix.csv`` is written from it.
        depth_size: (width, height) of the depth images (default 256×192).
        fps: the video's nominal frame rate (the odometry timestamps are the frames' true times).
        crf: libx264's constant rate factor (0 lossless … 51).
        preset: libx264's speed preset.
    """

    def __init__(self, root: Path, colour: Intrinsics, *, depth_size: tuple[int, int] = DEFAULT_DEPTH_SIZE, fps: float = 30.0,
                 crf: int = 0, preset: str = "veryfast", overwrite: bool = False) -> None:
        import imageio_ffmpeg

        if not isinstance(colour, Intrinsics):
            raise InvalidInputError(f"colour: expected Intrinsics, got {type(colour).__name__}")
        if not colour.distortion.is_zero:
            raise InvalidInputError("colour: the Stray layout holds a pinhole matrix only; got intrinsics with distortion")
        if colour.width % 2 or colour.height % 2:
            raise InvalidInputError(f"colour: expected an even width and height (NV21), got {colour.width}×{colour.height}")
        self.crf = int(check_number(crf, "crf", low=0, high=51, integer=True))
        self.fps = check_number(fps, "fps", low=0.0, low_open=True)
        dw, dh = (int(v) for v in depth_size)
        if dw <= 0 or dh <= 0:
            raise InvalidInputError(f"depth_size: expected a positive width and height, got {depth_size}")
        self.root, self.colour, self.depth_size = Path(root), colour, (dw, dh)
        existing = [n for n in _OWNED if (self.root / n).exists()]
        if existing and not overwrite:
            raise InvalidInputError(f"{self.root}: already holds a capture ({', '.join(existing)}); pass overwrite=True to replace it")
        for n in existing:
            p = self.root / n
            shutil.rmtree(p) if p.is_dir() else p.unlink()
        for sub in ("depth", "confidence"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)
        K = colour.K
        (self.root / "camera_matrix.csv").write_text("\n".join(",".join(repr(float(v)) for v in row) for row in K) + "\n")
        self._odometry = open(self.root / "odometry.csv", "w")
        self._odometry.write(", ".join(ODOMETRY_HEADER) + "\n")
        self._video = imageio_ffmpeg.write_frames(
            str(self.root / "rgb.mp4"), (colour.width, colour.height), pix_fmt_in="nv21", pix_fmt_out="yuv420p", fps=self.fps,
            quality=None, codec="libx264", macro_block_size=2, ffmpeg_log_level="error",
            output_params=["-crf", str(self.crf), "-preset", preset, "-threads", "1", "-colorspace", "smpte170m",
                           "-color_range", "tv"])
        self._video.send(None)
        self.frames = 0
        self.depth_frames = 0
        self._last_ns: int | None = None

    def write_colour(self, timestamp_ns: int, T_world_from_cam: RigidTransform, image: np.ndarray) -> int:
        """Append a video frame and its odometry row; returns its frame number (0, 1, …).

        Args:
            timestamp_ns: its time (strictly increasing).
            T_world_from_cam: the colour camera's pose in our world (OpenCV axes).
            image: an NV21 buffer (H·3/2, W) uint8 or an (H, W, 3) uint8 sRGB image (encoded to NV21).
        """
        img = check_array(image, "image", dtype=np.uint8)
        h, w = self.colour.height, self.colour.width
        if img.shape == (h, w, 3):
            img = encode_nv21(img)
        elif img.shape != (h * 3 // 2, w):
            raise InvalidInputError(f"image: expected NV21 ({h * 3 // 2}, {w}) or RGB ({h}, {w}, 3) uint8, got {img.shape}")
        ns = int(timestamp_ns)
        if self._last_ns is not None and ns <= self._last_ns:
            raise InvalidInputError(f"timestamp_ns: expected > {self._last_ns} (strictly increasing), got {ns}")
        T = pose_to_arkit(T_world_from_cam)
        t, q = T.translation, T.quaternion_xyzw()
        frame = self.frames
        self._video.send(np.ascontiguousarray(img))
        values = ", ".join(repr(float(v)) for v in (*t, *q))
        self._odometry.write(f"{_format_seconds(ns)}, {frame:06d}, {values}\n")
        self.frames += 1
        self._last_ns = ns
        return frame

    def write_depth(self, frame: int, depth_m: np.ndarray, known: np.ndarray, levels: np.ndarray) -> None:
        """Write frame ``frame``'s depth (z-depth in metres where ``known``) and confidence levels (0 / 1 / 2),
        all (H, W) at ``depth_size``."""
        dw, dh = self.depth_size
        depth = check_array(depth_m, "depth_m", shape=(dh, dw), dtype="float")
        mask = check_array(known, "known", shape=(dh, dw), dtype="bool")
        lv = check_array(levels, "levels", shape=(dh, dw), dtype=("int", "uint"))
        if lv.size and (lv.min() < 0 or lv.max() > 2):
            raise InvalidInputError(f"levels: expected 0, 1 or 2, got values in [{lv.min()}, {lv.max()}]")
        frame = int(frame)
        if frame < 0:
            raise InvalidInputError(f"frame: expected >= 0, got {frame}")
        with np.errstate(invalid="ignore"):
            mm = np.where(mask & np.isfinite(depth), np.rint(depth.astype(np.float64) * DEPTH_UNITS_PER_M), 0.0)
        mm = np.where((mm > 0) & (mm <= 65535), mm, 0).astype(np.uint16)
        for path, img in ((self.root / "depth" / f"{frame:06d}.png", mm),
                          (self.root / "confidence" / f"{frame:06d}.png", lv.astype(np.uint8))):
            if not cv2.imwrite(str(path), img):
                raise OSError(f"{path}: could not write PNG")
        self.depth_frames += 1

    def close(self) -> None:
        """Finish the video and the odometry file (idempotent)."""
        if self._video is not None:
            video, self._video = self._video, None
            video.close()
        if self._odometry is not None:
            self._odometry.close()
            self._odometry = None

    def __enter__(self) -> "StrayWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
