"""TUM RGB-D sequences: read and write the public benchmark's directory layout.

A sequence directory holds::

    sequence/
      rgb.txt            "# comment" lines, then "<timestamp_s> rgb/<name>.png" per colour image
      depth.txt          "<timestamp_s> depth/<name>.png" per depth image
      groundtruth.txt    "<timestamp_s> tx ty tz qx qy qz qw": T_world_from_cam, the pose of the colour
                         camera's optical frame (OpenCV axes) in the world; usually at another rate (100 Hz
                         motion capture) than the images (30 Hz)
      rgb/*.png          8-bit sRGB, 3 channels
      depth/*.png        16-bit unsigned, 5000 units per metre (1 unit = 0.2 mm), 0 = no measurement;
                         z-depth registered to the colour image (same intrinsics, same optical frame)
      calibration.json   optional (not in the public benchmark): ``Calibration.to_dict()`` of a ``kinect``
                         sensor, plus ``"format": "rgbd-envmap-tum", "version": 1`` when we wrote it

ICL-NUIM's TUM-compatible layout (``associations.txt``, ``*.gt.freiburg``) is read into the same
:class:`TumSequence` by :mod:`rgbd_envmap.icl`.

Intrinsics come from ``calibration.json`` when present (its ``depth`` and ``colour`` intrinsics must be
equal and ``T_colour_from_depth`` the identity, since depth is registered to colour), else the
benchmark's recommended default for the registered images, :data:`TUM_DEFAULT_INTRINSICS` (fx = fy =
525, cx = 319.5, cy = 239.5, 640×480, no distortion). ``intrinsics=`` overrides both: an
:class:`Intrinsics`, a preset of :data:`TUM_INTRINSICS` (``"fr1"``, ``"fr2"``, ``"fr3"``: the
benchmark's calibration of each Kinect's colour camera, which the registered depth shares;
``"default"``), or ``"auto"``: ``calibration.json``, else the preset the folder's name names
(``rgbd_dataset_freiburg2_desk`` → ``"fr2"``, :func:`tum_camera_from_name`), else ``"default"``.
:attr:`TumSequence.intrinsics_source` says which was used and why.

Depth: ``depth_scale`` PNG units per metre (5000, the benchmark's), times ``depth_correction``. The
benchmark lists a depth correction factor per camera (:data:`TUM_DEPTH_CORRECTION`: 1.035 for
freiburg1, 1.031 for freiburg2, 1.000 for freiburg3), found by comparing the Kinects' depth with the
depth of a checkerboard seen by the colour camera; its page (as copies of it quote it) says the
published depth images are already pre-scaled, so the default is 1 and the factor is for raw
recordings of those cameras (it multiplies the metric depth).

Poses come from ``groundtruth.txt`` or from any trajectory file in the same format (``trajectory=``, an
estimated trajectory), both read by :func:`rgbd_envmap.logs.read_tum_trajectory`, or from a ``.log``
trajectory (:class:`LogTrajectory`: one matrix per frame number, frame ``i`` being the ``i``-th line of
``depth.txt``).

Association (:func:`read_tum_sequence`): the depth image is the frame's clock. Depth and colour images
are paired as the benchmark's ``associate.py`` pairs them: among all pairs within ``max_dt_s``, greedily
by smallest time difference, each image used at most once. Each pair then takes the pose nearest to
its depth timestamp (``poses="nearest"``, the default) or the pose interpolated at that timestamp
between the two poses around it (``poses="linear"``: linear in translation, slerp in rotation), in both
cases only from poses within ``max_dt_s``. Depth images left without a colour image or a pose are
skipped and counted by reason in :attr:`TumSequence.skipped`.

Timestamps are parsed as text into integer nanoseconds (no float round trip): the benchmark writes 6
decimals for images and 4 for poses. The writer writes 6 decimals (``timestamp_decimals=9`` for
timestamps finer than a microsecond; a finer one with 6 raises instead of rounding), so a written
``timestamp_ns`` always reads back exactly. Poses are written with ``%.17g`` (the benchmark prints 4
decimals); a read pose matrix is rebuilt from its quaternion and matches the written one to ~1e-15.

Errors: every problem with a file raises :class:`~rgbd_envmap.errors.LogFormatError` naming the file,
and the line for text files (missing file, wrong field count, malformed or non-increasing timestamp,
NaN or non-unit quaternion, unreadable or truncated PNG, wrong PNG dtype, channels or size). Bad
arguments raise the matching :mod:`rgbd_envmap.errors` class. No frame is ever returned half-read.

References:
    Sturm, Engelhard, Endres, Burgard, Cremers, "A Benchmark for the Evaluation of RGB-D SLAM Systems",
    IROS 2012; and the benchmark's "File Formats" page (cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats).
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Iterable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from rgbd_envmap.checks import check_array, check_method, check_number
from rgbd_envmap.errors import (
    InvalidInputError,
    LogFormatError,
    RangeError,
    RgbdEnvmapError,
)
from rgbd_envmap.logs import read_log_trajectory, read_timestamped_table, read_tum_trajectory, trajectory_format
from rgbd_envmap.types import Calibration, Distortion, Intrinsics, RigidTransform

__all__ = [
    "TUM_DEFAULT_INTRINSICS",
    "TUM_DEPTH_CORRECTION",
    "TUM_DEPTH_SCALE",
    "TUM_INTRINSICS",
    "TumAssociation",
    "TumFrame",
    "TumSequence",
    "TumTrajectory",
    "LogTrajectory",
    "open_trajectory",
    "read_tum_sequence",
    "tum_camera_from_name",
    "write_tum_sequence",
]

#: Intrinsics of the benchmark's registered depth and colour images ("ROS default"), no distortion.
TUM_DEFAULT_INTRINSICS = Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
#: The benchmark's published calibration of each Kinect's colour camera (fx, fy, cx, cy and
#: d0 … d4 = OpenCV's k1, k2, p1, p2, k3; freiburg3's images are already undistorted), and the ROS
#: default the benchmark recommends when undistortion is not wanted. The registered depth images
#: share the colour camera's pixel grid, hence its intrinsics.
TUM_INTRINSICS = {
    "fr1": Intrinsics(640, 480, 517.3, 516.5, 318.6, 255.3, Distortion(0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": Intrinsics(640, 480, 520.9, 521.0, 325.1, 249.7, Distortion(0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": Intrinsics(640, 480, 535.4, 539.2, 320.1, 247.6),
    "default": TUM_DEFAULT_INTRINSICS,
}
#: The benchmark's depth correction factor per camera (applied as metric depth × factor; its page says
#: the published depth images are already pre-scaled).
TUM_DEPTH_CORRECTION = {"fr1": 1.035, "fr2": 1.031, "fr3": 1.0, "default": 1.0}
#: Depth PNG units per metre.
TUM_DEPTH_SCALE = 5000.0
#: Largest z-depth a 16-bit PNG can hold, metres.
TUM_MAX_DEPTH_M = 65535 / TUM_DEPTH_SCALE

FORMAT, VERSION = "rgbd-envmap-tum", 1
_FRAME_NAMES = ("world", "colour")
_OWNED = ("rgb", "depth", "rgb.txt", "depth.txt", "groundtruth.txt", "calibration.json")
_POSE_METHODS = ("nearest", "linear")
_FREIBURG_RE = re.compile(r"rgbd_dataset_freiburg([123])_")


def tum_camera_from_name(path: str | Path) -> str | None:
    """The :data:`TUM_INTRINSICS` preset that a sequence folder's name names, or None: the
    benchmark's folders are ``rgbd_dataset_freiburgN_<name>`` (N = 1, 2, 3 → ``"frN"``). Only the
    folder's own name counts (not its parents'), and only when it names exactly one camera."""
    name = Path(os.path.abspath(path)).name  # "." and ".." name the folder; a symlink keeps its own name
    found = set(_FREIBURG_RE.findall(name))
    return f"fr{found.pop()}" if len(found) == 1 else None


@dataclass(frozen=True)
class TumAssociation:
    """One associated frame of a sequence (files not read yet).

    Attributes:
        timestamp_ns: the depth image's timestamp, the frame's clock.
        depth_path, rgb_path: the images (sequence root / index entry). rgb_timestamp_ns: the colour image's timestamp.
        depth_line, rgb_line: 1-based line numbers in depth.txt / rgb.txt (for error messages).
        T_world_from_cam: the colour camera's pose at ``timestamp_ns`` (nearest or interpolated).
        pose_dt_ns: pose time minus ``timestamp_ns`` for the nearest pose; 0 when interpolated.
    """

    timestamp_ns: int
    depth_path: Path
    rgb_timestamp_ns: int
    rgb_path: Path
    depth_line: int
    rgb_line: int
    T_world_from_cam: RigidTransform
    pose_dt_ns: int = 0


@dataclass(frozen=True)
class TumFrame:
    """One RGB-D frame of a TUM sequence, depth registered to colour.

    Attributes:
        timestamp_ns: capture time of the depth image, integer nanoseconds.
        rgb: (H, W, 3) uint8 sRGB-encoded colour (not linear; ``rgbd_envmap.colour.srgb_to_linear``).
        depth_m: (H, W) float32 z-depth in metres; 0 where not ``known`` (the PNG's sentinel).
        known: (H, W) bool, True where the sensor measured a depth.
        T_world_from_cam: pose of the colour camera's optical frame (OpenCV axes), frames
            ("world", "colour").
        rgb_timestamp_ns: capture time of the colour image (None: same as ``timestamp_ns``).

    Arrays are validated and made read-only on construction.
    """

    timestamp_ns: int
    rgb: np.ndarray
    depth_m: np.ndarray
    known: np.ndarray
    T_world_from_cam: RigidTransform
    rgb_timestamp_ns: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "timestamp_ns", int(self.timestamp_ns))
        if self.rgb_timestamp_ns is not None:
            object.__setattr__(self, "rgb_timestamp_ns", int(self.rgb_timestamp_ns))
        rgb = check_array(self.rgb, "rgb", shape=("H", "W", 3), dtype=np.uint8)
        depth = check_array(self.depth_m, "depth_m", shape=rgb.shape[:2], dtype="float")
        known = check_array(self.known, "known", shape=rgb.shape[:2], dtype="bool")
        if not isinstance(self.T_world_from_cam, RigidTransform):
            raise InvalidInputError(f"T_world_from_cam: expected a RigidTransform, got {type(self.T_world_from_cam).__name__}")
        for name, arr in (("rgb", rgb), ("depth_m", depth.astype(np.float32, copy=False)), ("known", known)):
            arr = np.array(arr, copy=True)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)


class TumSequence:
    """A TUM RGB-D sequence opened for reading; images are read lazily by :meth:`load`.

    Attributes:
        root: the sequence directory.
        intrinsics: of the registered depth and colour images.
        calibration: the ``calibration.json`` contents, or None when it was not read (absent, or
            ``intrinsics=`` given).
        frames: list of :class:`TumAssociation` in depth-timestamp order.
        skipped: {"no_rgb": n, "no_pose": n} depth images dropped by the association, and
            {"rgb_unused": n} colour images that no depth image took.
        max_dt_s, poses: the association settings used.
        intrinsics_source: (name, reason): the preset name (``"fr1"`` …, ``"default"``),
            ``"calibration.json"`` or ``"given"``, and why it was chosen, in words.
        depth_scale: PNG units per metre; depth_correction: factor on the metric depth.
        trajectory: the pose file read (``groundtruth.txt`` unless another was given).
        index_names: the index files that name the depth and colour images (for error messages); None
            for a folder of numbered images (errors then name the frame number).
    """

    def __init__(self, root: Path, intrinsics: Intrinsics, calibration: Calibration | None, frames: list[TumAssociation],
                 skipped: dict[str, int], max_dt_s: float, poses: str, *,
                 intrinsics_source: tuple[str, str] = ("given", "given by the caller"),
                 depth_scale: float = TUM_DEPTH_SCALE, depth_correction: float = 1.0,
                 trajectory: Path | None = None, index_names: tuple[str, str] | None = ("depth.txt", "rgb.txt")) -> None:
        """Use :func:`read_tum_sequence` (or :func:`rgbd_envmap.icl.read_icl_nuim_sequence`)."""
        self.root, self.intrinsics, self.calibration = root, intrinsics, calibration
        self.frames, self.skipped, self.max_dt_s, self.poses = frames, skipped, max_dt_s, poses
        self.intrinsics_source = intrinsics_source
        self.depth_scale = check_number(depth_scale, "depth_scale", low=0.0, low_open=True)
        self.depth_correction = check_number(depth_correction, "depth_correction", low=0.0, low_open=True)
        self.trajectory = trajectory if trajectory is not None else Path(root) / "groundtruth.txt"
        self.index_names = index_names

    @property
    def pipeline_calibration(self) -> Calibration:
        """The :class:`Calibration` a pipeline runs this sequence with: ``calibration.json``'s when it
        was read, else a ``kinect`` calibration of :attr:`intrinsics` for both cameras (registered
        depth: identity extrinsics), 30 Hz."""
        if self.calibration is not None:
            return self.calibration
        return Calibration("kinect", self.intrinsics, self.intrinsics, RigidTransform.identity("colour", "depth"), 30.0, 30.0)

    def __len__(self) -> int:
        return len(self.frames)

    def __iter__(self) -> Iterator[TumFrame]:
        for i in range(len(self.frames)):
            yield self.load(i)

    def __getitem__(self, i: int) -> TumFrame:
        return self.load(i)

    @property
    def timestamps_ns(self) -> np.ndarray:
        """(N,) int64 depth timestamps of the associated frames."""
        return np.array([a.timestamp_ns for a in self.frames], dtype=np.int64)

    def load(self, i: int) -> TumFrame:
        """Read the ``i``-th associated frame's images.

        Raises:
            LogFormatError: an image is missing, unreadable, truncated, or has the wrong dtype, channel
                count or size for :attr:`intrinsics`; the message names the file and its index line.
        """
        a = self.frames[i]
        h, w = self.intrinsics.shape
        if self.index_names is None:  # a folder of numbered images (Redwood): no index file to name
            d_where = c_where = f"frame {a.depth_line - 1}"
        else:
            d_where, c_where = f"{self.index_names[0]} line {a.depth_line}", f"{self.index_names[1]} line {a.rgb_line}"
        depth = _read_png(a.depth_path, d_where)
        if depth.dtype != np.uint16 or depth.ndim != 2:
            raise LogFormatError(f"{a.depth_path} ({d_where}): expected a single-channel 16-bit depth PNG, "
                                 f"got dtype {depth.dtype} with shape {depth.shape}")
        if depth.shape != (h, w):
            raise LogFormatError(f"{a.depth_path} ({d_where}): expected {h}×{w} from the intrinsics, got {depth.shape}")
        bgr = _read_png(a.rgb_path, c_where, jpeg=True)
        if bgr.dtype != np.uint8 or bgr.ndim != 3 or bgr.shape[2] != 3:
            raise LogFormatError(f"{a.rgb_path} ({c_where}): expected an 8-bit 3-channel colour PNG, "
                                 f"got dtype {bgr.dtype} with shape {bgr.shape}")
        if bgr.shape[:2] != (h, w):
            raise LogFormatError(f"{a.rgb_path} ({c_where}): expected {h}×{w} from the intrinsics, got {bgr.shape[:2]}")
        known = depth > 0
        metres = depth / self.depth_scale
        if self.depth_correction != 1.0:
            metres = metres * self.depth_correction
        depth_m = metres.astype(np.float32)
        return TumFrame(a.timestamp_ns, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), depth_m, known, a.T_world_from_cam, a.rgb_timestamp_ns)


def _read_bytes(path: Path, where: str = "") -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        why = "missing file" if isinstance(exc, FileNotFoundError) else str(exc)
        raise LogFormatError(f"{path}{f' ({where})' if where else ''}: {why}") from None


def _read_png(path: Path, where: str, *, jpeg: bool = False) -> np.ndarray:
    """A PNG (or with ``jpeg`` also a JPEG: the Redwood data's colour images) decoded as stored."""
    data = _read_bytes(path, where)
    is_jpeg = jpeg and data.startswith(b"\xff\xd8\xff")
    if not (data.startswith(b"\x89PNG\r\n\x1a\n") or is_jpeg):
        raise LogFormatError(f"{path} ({where}): not a PNG{' or JPEG' if jpeg else ''} file")
    if is_jpeg and not data.rstrip(b"\x00").endswith(b"\xff\xd9"):  # libjpeg pads a truncated file and says nothing
        raise LogFormatError(f"{path} ({where}): truncated JPEG (no end-of-image marker)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)  # libpng rejects truncation and CRC errors
    if img is None:
        raise LogFormatError(f"{path} ({where}): unreadable, truncated or corrupt {'JPEG' if is_jpeg else 'PNG'}")
    return img


def _read_images(root: Path, name: str) -> list[tuple[int, int, Path]]:
    path = root / name
    out = []
    for lineno, ns, (rel,) in read_timestamped_table(path, 2):
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            raise LogFormatError(f"{path}, line {lineno}: image path must be relative to the sequence, got {rel!r}")
        out.append((lineno, ns, root / rel))
    return out


def _read_groundtruth(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N,) int64 timestamps, (N, 3) translations, (N, 4) unit quaternions xyzw of groundtruth.txt."""
    stamps, translations, quaternions = read_tum_trajectory(path)
    unit = np.array([q / np.linalg.norm(q) for q in quaternions], dtype=np.float64).reshape(-1, 4)
    return stamps, translations, unit


class TumTrajectory:
    """A trajectory file in TUM RGB-D format (``timestamp tx ty tz qx qy qz qw``: T_world_from_cam of
    the colour camera), read by :func:`rgbd_envmap.logs.read_tum_trajectory`, for pose look-ups by time.

    Raises:
        LogFormatError: the file is missing or malformed (naming the file and line).
    """

    format = "tum"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.timestamps_ns, self.translations, self.quaternions = _read_groundtruth(self.path)

    def __len__(self) -> int:
        return len(self.timestamps_ns)

    def pose_at(self, timestamp_ns: int, max_dt_ns: int, method: str = "nearest", index: int | None = None
                ) -> tuple[RigidTransform, int] | None:
        """The pose at ``timestamp_ns`` as ``(T_world_from_cam, pose time − timestamp_ns)``, or None
        when no pose lies within ``max_dt_ns``: the nearest pose (``"nearest"``) or the one
        interpolated between the two poses around it, each within ``max_dt_ns`` (``"linear"``: linear
        in translation, slerp in rotation; the time offset is then 0). ``index`` (the frame's number)
        is not used: a TUM trajectory is looked up by time."""
        check_method(method, _POSE_METHODS, "poses")
        return _pose_at(int(timestamp_ns), self.timestamps_ns, self.translations, self.quaternions, int(max_dt_ns), method)


class LogTrajectory:
    """A trajectory file in the ``.log`` format (:func:`rgbd_envmap.logs.read_log_trajectory`: one
    4×4 T_world_from_cam per frame index), for pose look-ups by frame number.

    Raises:
        LogFormatError: the file is missing or malformed (naming the file and line).
    """

    format = "log"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.frame_ids, self.matrices = read_log_trajectory(self.path)
        self._by_id = {int(k): j for j, k in enumerate(self.frame_ids)}

    def __len__(self) -> int:
        return len(self.frame_ids)

    def pose_at(self, timestamp_ns: int, max_dt_ns: int, method: str = "nearest", index: int | None = None
                ) -> tuple[RigidTransform, int] | None:
        """``(T_world_from_cam, 0)`` of frame ``index`` (its position in the sequence, from 0), or None
        when the file has no block for it; the time arguments are not used (a ``.log`` names frames,
        not times)."""
        check_method(method, _POSE_METHODS, "poses")
        if index is None:
            raise InvalidInputError("index: a .log trajectory is looked up by frame number, got None")
        j = self._by_id.get(int(index))
        return None if j is None else (RigidTransform(self.matrices[j], *_FRAME_NAMES), 0)


def open_trajectory(path: str | Path) -> TumTrajectory | LogTrajectory:
    """The trajectory file ``path`` in either format it may have, told by its content
    (:func:`rgbd_envmap.logs.trajectory_format`): TUM RGB-D (looked up by time) or ``.log`` (by frame
    number: frame ``i`` is the ``i``-th frame of the sequence, from 0, in the order it is read)."""
    path = Path(path)
    return LogTrajectory(path) if trajectory_format(path) == "log" else TumTrajectory(path)


def _read_calibration(path: Path) -> Calibration:
    try:
        d = json.loads(_read_bytes(path))
    except json.JSONDecodeError as exc:
        raise LogFormatError(f"{path}, line {exc.lineno}: invalid JSON ({exc.msg})") from None
    try:
        if not isinstance(d, dict):
            raise TypeError(f"expected a JSON object, got {type(d).__name__}")
        if "format" in d and (d["format"] != FORMAT or d.get("version") != VERSION):
            raise ValueError(f"expected format {FORMAT!r} version {VERSION}, got {d['format']!r} {d.get('version')!r}")
        calibration = Calibration.from_dict(d)
    except (ValueError, KeyError, TypeError, AttributeError, RgbdEnvmapError) as exc:
        raise LogFormatError(f"{path}: invalid calibration ({type(exc).__name__}: {exc})") from None
    if calibration.depth != calibration.colour:
        raise LogFormatError(f"{path}: TUM depth is registered to colour, so depth and colour intrinsics must be equal; "
                             f"got {calibration.depth} and {calibration.colour}")
    if np.abs(calibration.T_colour_from_depth.matrix - np.eye(4)).max() > 1e-9:
        raise LogFormatError(f"{path}: TUM depth is registered to colour, so T_colour_from_depth must be the identity")
    return calibration


def _associate(depth: list[tuple[int, int, Path]], rgb: list[tuple[int, int, Path]], max_dt_ns: int) -> dict[int, int]:
    """{depth index: rgb index}: greedy by smallest |dt| over all pairs within ``max_dt_ns``, one-to-one."""
    d_ns = np.array([r[1] for r in depth], dtype=np.int64)
    c_ns = np.array([r[1] for r in rgb], dtype=np.int64)
    candidates = []
    lo = np.searchsorted(c_ns, d_ns - max_dt_ns, side="left")
    hi = np.searchsorted(c_ns, d_ns + max_dt_ns, side="right")
    for i in range(len(d_ns)):
        for j in range(lo[i], hi[i]):
            candidates.append((abs(int(d_ns[i]) - int(c_ns[j])), i, j))
    candidates.sort()
    pairs, used = {}, set()
    for _, i, j in candidates:
        if i not in pairs and j not in used:
            pairs[i] = j
            used.add(j)
    return pairs


def _pose_at(ns: int, stamps: np.ndarray, trans: np.ndarray, quats: np.ndarray, max_dt_ns: int,
             method: str) -> tuple[RigidTransform, int] | None:
    k = int(np.searchsorted(stamps, ns))
    if method == "linear":
        if k < len(stamps) and stamps[k] == ns:
            return RigidTransform.from_quaternion(trans[k], quats[k], *_FRAME_NAMES), 0
        if k == 0 or k == len(stamps) or ns - stamps[k - 1] > max_dt_ns or stamps[k] - ns > max_dt_ns:
            return None
        t0, t1 = int(stamps[k - 1]), int(stamps[k])
        a = (ns - t0) / (t1 - t0)
        r = Slerp([0.0, 1.0], Rotation.from_quat(quats[k - 1:k + 1]))([a])[0]
        t = (1.0 - a) * trans[k - 1] + a * trans[k]
        return RigidTransform.from_rt(r.as_matrix(), t, *_FRAME_NAMES), 0
    best = None
    for j in (k - 1, k):
        if 0 <= j < len(stamps) and (best is None or abs(int(stamps[j]) - ns) < abs(int(stamps[best]) - ns)):
            best = j
    if best is None or abs(int(stamps[best]) - ns) > max_dt_ns:
        return None
    return RigidTransform.from_quaternion(trans[best], quats[best], *_FRAME_NAMES), int(stamps[best]) - ns


def read_tum_sequence(path: str | Path, *, max_dt_s: float = 0.02, poses: str = "nearest",
                      intrinsics: Intrinsics | str | None = None, depth_scale: float = TUM_DEPTH_SCALE,
                      depth_correction: float = 1.0, trajectory: str | Path | None = None) -> TumSequence:
    """Open a TUM RGB-D sequence and associate its depth images, colour images and poses.

    Args:
        path: the sequence directory (holding rgb.txt, depth.txt, groundtruth.txt).
        max_dt_s: largest |time difference| in seconds between a depth image and its colour image, and
            between a depth image and its pose (``"nearest"``) or each of the two poses around it
            (``"linear"``). The benchmark's ``associate.py`` uses 0.02 s.
        poses: ``"nearest"`` (the pose nearest in time) or ``"linear"`` (interpolated: linear in
            translation, slerp in rotation).
        intrinsics: None (``calibration.json`` if present, else :data:`TUM_DEFAULT_INTRINSICS`), an
            :class:`Intrinsics` or a :data:`TUM_INTRINSICS` preset name (both override
            ``calibration.json``), or ``"auto"``: ``calibration.json``, else the preset the folder's name
            names (:func:`tum_camera_from_name`), else ``"default"``.
        depth_scale: depth PNG units per metre (> 0; the benchmark's 5000).
        depth_correction: factor on the metric depth (> 0; e.g. ``TUM_DEPTH_CORRECTION["fr1"]`` for a
            freiburg1 recording that does not carry it yet; 1 for the published images).
        trajectory: a pose file to use instead of ``groundtruth.txt`` (e.g. an estimated trajectory), in
            TUM format or the ``.log`` format (:func:`open_trajectory`; a ``.log`` block ``i`` is the
            ``i``-th line of depth.txt, from 0); a relative path is relative to the working directory.

    Returns:
        A :class:`TumSequence`; images are read when a frame is loaded.

    Raises:
        LogFormatError: a missing or malformed index, pose or calibration file (naming file and line).
        InvalidInputError / RangeError / UnknownMethodError: bad arguments.
    """
    root = Path(path)
    if not root.is_dir():
        raise LogFormatError(f"{root}: not a directory (expected a TUM RGB-D sequence)")
    max_dt_s = check_number(max_dt_s, "max_dt_s", low=0.0)
    check_method(poses, _POSE_METHODS, "poses")
    depth_scale = check_number(depth_scale, "depth_scale", low=0.0, low_open=True)
    depth_correction = check_number(depth_correction, "depth_correction", low=0.0, low_open=True)
    calibration = None
    if intrinsics is None or intrinsics == "auto":
        auto = intrinsics == "auto"
        camera = tum_camera_from_name(root) if auto else None
        if (root / "calibration.json").is_file():
            calibration = _read_calibration(root / "calibration.json")
            intrinsics = calibration.colour
            source = ("calibration.json", "calibration.json in the sequence folder")
        elif camera is not None:
            intrinsics = TUM_INTRINSICS[camera]
            source = (camera, f"no calibration.json; the folder name {Path(os.path.abspath(root)).name!r} names "
                              f"freiburg{camera[2]}")
        else:
            intrinsics = TUM_DEFAULT_INTRINSICS
            source = ("default", "no calibration.json" + (" and the folder name names no freiburg camera" if auto else ""))
    elif isinstance(intrinsics, str):
        check_method(intrinsics, (*TUM_INTRINSICS, "auto"), "intrinsics")
        source = (intrinsics, "given by name")
        intrinsics = TUM_INTRINSICS[intrinsics]
    elif isinstance(intrinsics, Intrinsics):
        source = ("given", "given by the caller")
    else:
        raise InvalidInputError(f"intrinsics: expected an Intrinsics, a preset name or 'auto', got {type(intrinsics).__name__}")
    depth = _read_images(root, "depth.txt")
    rgb = _read_images(root, "rgb.txt")
    trajectory_path = root / "groundtruth.txt" if trajectory is None else Path(trajectory)
    track = open_trajectory(trajectory_path)
    max_dt_ns = round(max_dt_s * 1e9)
    pairs = _associate(depth, rgb, max_dt_ns)
    frames: list[TumAssociation] = []
    skipped = {"no_rgb": len(depth) - len(pairs), "no_pose": 0, "rgb_unused": len(rgb) - len(pairs)}
    for i in sorted(pairs):
        d_line, d_ns, d_path = depth[i]
        c_line, c_ns, c_path = rgb[pairs[i]]
        pose = track.pose_at(d_ns, max_dt_ns, poses, index=i)
        if pose is None:
            skipped["no_pose"] += 1
            continue
        frames.append(TumAssociation(d_ns, d_path, c_ns, c_path, d_line, c_line, pose[0], pose[1]))
    return TumSequence(root, intrinsics, calibration, frames, skipped, max_dt_s, poses, intrinsics_source=source,
                       depth_scale=depth_scale, depth_correction=depth_correction, trajectory=trajectory_path)


def _format_stamp(ns: int, decimals: int) -> str:
    if decimals == 6:
        return f"{ns // 10**9}.{(ns % 10**9) // 1000:06d}"
    return f"{ns // 10**9}.{ns % 10**9:09d}"


def _depth_png(frame: object, i: int, h: int, w: int) -> np.ndarray:
    depth = check_array(frame.depth_m, f"frames[{i}].depth_m", shape=(h, w), dtype="float")
    known = check_array(frame.known, f"frames[{i}].known", shape=(h, w), dtype="bool")
    d = depth[known].astype(np.float64)
    finite = np.isfinite(d)
    if d.size and not (finite.all() and d.min() >= 0.5 / TUM_DEPTH_SCALE and d.max() <= TUM_MAX_DEPTH_M):
        got = f"[{d[finite].min()}, {d[finite].max()}]" if finite.any() else "no finite value"
        raise RangeError(f"frames[{i}].depth_m: known depths must be finite and in [{0.5 / TUM_DEPTH_SCALE}, "
                         f"{TUM_MAX_DEPTH_M}] m to fit a 16-bit PNG at {TUM_DEPTH_SCALE:g} units/m, got {got}"
                         + (f" and {int((~finite).sum())} NaN or inf" if not finite.all() else ""))
    out = np.zeros((h, w), dtype=np.uint16)
    out[known] = np.rint(d * TUM_DEPTH_SCALE).astype(np.uint16)
    return out


_HEADERS = {
    "rgb.txt": ["# color images", "# rgbd-envmap: 8-bit sRGB", "# timestamp filename"],
    "depth.txt": ["# depth maps", f"# rgbd-envmap: 16-bit z-depth, {TUM_DEPTH_SCALE:g} units per metre, 0 = missing",
                  "# timestamp filename"],
    "groundtruth.txt": ["# ground truth trajectory", "# rgbd-envmap: T_world_from_cam of the colour camera (OpenCV axes)",
                        "# timestamp tx ty tz qx qy qz qw"],
}


def write_tum_sequence(path: str | Path, frames: Iterable[object], intrinsics: Intrinsics, *,
                       calibration_json: bool = True, overwrite: bool = False, timestamp_decimals: int = 6) -> int:
    """Write frames as a TUM RGB-D sequence (layout in the module docstring), streaming.

    Each frame's PNGs are written, then its index and pose lines are appended, so an error or a crash
    leaves a readable sequence of the frames before it. ``frames`` may be a generator (e.g.
    ``KinectSimulator.run``): nothing is held in memory beyond one frame.

    Args:
        path: the sequence directory; created if missing. An existing non-empty directory raises
            :class:`LogFormatError` unless ``overwrite``, which removes only the entries this layout owns.
        frames: objects with the fields of :class:`TumFrame` (``timestamp_ns``, ``rgb`` (H, W, 3) uint8
            sRGB, ``depth_m`` (H, W) float z-depth in metres, ``known`` (H, W) bool, ``T_world_from_cam``,
            optionally ``rgb_timestamp_ns``), e.g. ``sim.kinect.KinectFrame`` or :class:`TumFrame`;
            strictly increasing timestamps. Depth is rounded to 1/5000 m; unknown pixels become 0.
        intrinsics: of the registered images; (H, W) must match every frame.
        calibration_json: also write ``calibration.json`` (a ``kinect`` :class:`Calibration`, 30 Hz).
        timestamp_decimals: 6 (the benchmark's; every timestamp must then be a whole microsecond) or 9.

    Returns:
        The number of frames written.

    Raises:
        ShapeError / DTypeError: a frame's array does not match ``intrinsics`` or has the wrong dtype.
        RangeError: a known depth is not finite or does not fit the 16-bit PNG (0.1 mm to 13.107 m).
        InvalidInputError: timestamps negative, not strictly increasing, or finer than ``timestamp_decimals``;
            a pose that is not a RigidTransform.
    """
    if not isinstance(intrinsics, Intrinsics):
        raise InvalidInputError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
    if timestamp_decimals not in (6, 9):
        raise InvalidInputError(f"timestamp_decimals: expected 6 or 9, got {timestamp_decimals!r}")
    root = Path(path)
    if root.is_dir() and any(root.iterdir()):
        if not overwrite:
            raise LogFormatError(f"{root}: directory exists and is not empty (pass overwrite=True)")
        for name in _OWNED:
            p = root / name
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    (root / "rgb").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(exist_ok=True)
    if calibration_json:
        cal = Calibration("kinect", intrinsics, intrinsics, RigidTransform.identity("colour", "depth"), 30.0, 30.0)
        (root / "calibration.json").write_text(json.dumps({"format": FORMAT, "version": VERSION, **cal.to_dict()}, indent=2))
    h, w = intrinsics.shape
    unit = 10 ** (9 - timestamp_decimals)
    with ExitStack() as stack:
        files = {name: stack.enter_context(open(root / name, "w", buffering=1, newline="\n")) for name in _HEADERS}
        for name, lines in _HEADERS.items():
            files[name].write("\n".join(lines) + "\n")
        last = (-1, -1)
        n = 0
        for i, f in enumerate(frames):
            d_ns = int(f.timestamp_ns)
            c_ns = getattr(f, "rgb_timestamp_ns", None)
            c_ns = d_ns if c_ns is None else int(c_ns)
            for name, ns, prev in (("timestamp_ns", d_ns, last[0]), ("rgb_timestamp_ns", c_ns, last[1])):
                if ns < 0 or ns <= prev:
                    raise InvalidInputError(f"frames[{i}].{name}: expected >= 0 and > the previous frame's {prev}, got {ns}")
                if ns % unit:
                    raise InvalidInputError(f"frames[{i}].{name}: {ns} ns is not a whole multiple of {unit} ns, so "
                                            f"{timestamp_decimals} decimals cannot hold it; pass timestamp_decimals=9")
            last = (d_ns, c_ns)
            rgb = check_array(f.rgb, f"frames[{i}].rgb", shape=(h, w, 3), dtype=np.uint8)
            depth = _depth_png(f, i, h, w)
            T = f.T_world_from_cam
            if not isinstance(T, RigidTransform):
                raise InvalidInputError(f"frames[{i}].T_world_from_cam: expected a RigidTransform, got {type(T).__name__}")
            d_stamp, c_stamp = _format_stamp(d_ns, timestamp_decimals), _format_stamp(c_ns, timestamp_decimals)
            for rel, img in ((f"depth/{d_stamp}.png", depth), (f"rgb/{c_stamp}.png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))):
                ok, png = cv2.imencode(".png", img)
                if not ok:
                    raise LogFormatError(f"{root / rel}: PNG encoding failed")
                (root / rel).write_bytes(png.tobytes())
            values = np.concatenate([T.translation, T.quaternion_xyzw()])
            files["groundtruth.txt"].write(d_stamp + " " + " ".join(f"{x:.17g}" for x in values) + "\n")
            files["depth.txt"].write(f"{d_stamp} depth/{d_stamp}.png\n")
            files["rgb.txt"].write(f"{c_stamp} rgb/{c_stamp}.png\n")
            n += 1
    return n
