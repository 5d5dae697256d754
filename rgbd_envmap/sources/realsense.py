"""Intel RealSense recordings (``.bag``), read through Open3D's ``open3d.t.io.RSBagReader``.

What the reader gives (Open3D's documented interface, which this module relies on and nothing more):

- ``RSBagReader()``, ``open(filename) -> bool``, ``close()``;
- ``metadata``: an ``RGBDVideoMetadata`` with ``intrinsics`` (an ``open3d.camera.PinholeCameraIntrinsic``
  of the colour stream: ``width``, ``height``, ``intrinsic_matrix`` 3×3; no distortion), ``depth_scale``
  (depth units per metre), ``fps``, ``width``, ``height``, ``color_format`` (``"RGB8"``, ``"BGR8"``,
  ``"RGBA8"``, ``"BGRA8"``), ``depth_format`` (``"Z16"``), ``stream_length_usec``, ``device_name``,
  ``serial_number``;
- ``next_frame()``: a ``t.geometry.RGBDImage`` whose ``depth`` (16-bit) is aligned to ``color``: the
  same viewpoint and pixel grid, so the colour intrinsics hold for both (an empty image at the end);
  ``is_eof()``; ``get_timestamp()``: the last frame's position in the recording, in microseconds.

The colour is passed on as the bag stores it, so a ``BGR8`` / ``BGRA8`` stream is reordered to RGB
here. Open3D's bag reader leaves ``depth_scale`` unset (0) in some versions; then the D400 series'
1 mm units (1000 per metre) are assumed and ``run.json`` says so (``--depth-scale`` overrides; the L515
stores 4000 per metre).

A bag holds no camera poses: they come from a trajectory file the caller gives (``poses`` / the CLI's
``--poses FILE``): the ``.log`` format (block ``i``: the ``i``-th frame the reader returns, from 0) or
TUM format (by the frame's time in the recording, seconds from its start, within ``max_dt_s``). Without
one, :func:`read_realsense_bag` fails naming ``--poses FILE``. Frames without a pose are skipped and
counted (``skipped["no_pose"]``).

References:
    Zhou, Park, Koltun (2018). Open3D: A Modern Library for 3D Data Processing. arXiv:1801.09847 (the
    ``t.io.RSBagReader`` interface). Intel RealSense SDK 2.0, rs_sensor.h (the pixel formats).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from rgbd_envmap.checks import check_number
from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.tum import TumFrame, open_trajectory
from rgbd_envmap.types import Calibration, Intrinsics, RigidTransform

__all__ = ["RealSenseBag", "read_realsense_bag", "is_realsense_bag", "find_bag", "D400_DEPTH_SCALE"]

#: depth units per metre of the D400 series (1 mm), assumed when the bag's metadata holds none.
D400_DEPTH_SCALE = 1000.0
_COLOUR_ORDER = {"RGB8": (0, 1, 2), "BGR8": (2, 1, 0), "RGBA8": (0, 1, 2), "BGRA8": (2, 1, 0)}


def find_bag(path: str | Path) -> Path | None:
    """The ``.bag`` file ``path`` names: itself, or the one ``*.bag`` in the folder ``path``; else None."""
    p = Path(path)
    if p.is_file():
        return p if p.suffix.lower() == ".bag" else None
    if p.is_dir():
        found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() == ".bag")
        return found[0] if len(found) == 1 else None
    return None


def is_realsense_bag(path: str | Path) -> bool:
    """True for a ``.bag`` file, or a folder holding exactly one."""
    return find_bag(path) is not None


def _default_reader():
    import open3d as o3d

    return o3d.t.io.RSBagReader()


def _array(image) -> np.ndarray:
    return np.asarray(image.as_tensor().numpy() if hasattr(image, "as_tensor") else image)


class RealSenseBag:
    """A RealSense bag opened for reading (:func:`read_realsense_bag`); frames are read by iterating.

    Attributes:
        path: the ``.bag`` file. calibration: a ``"kinect"`` (registered RGB-D) calibration of the
            colour camera, at the bag's frame rate. intrinsics, intrinsics_source: the camera and
            ``(name, reason)``. depth_scale, depth_scale_source: units per metre and where from.
        metadata: the reader's metadata as a dict (device, serial number, formats, fps, length).
        trajectory: the pose file. skipped: ``no_pose`` (frames without a pose), filled while iterating.
    """

    def __init__(self, path: Path, trajectory: Path, *, intrinsics: Intrinsics | None = None,
                 depth_scale: float | None = None, max_dt_s: float = 0.02, reader_factory: Callable | None = None) -> None:
        """Use :func:`read_realsense_bag`."""
        self.path, self.trajectory = Path(path), Path(trajectory)
        self.max_dt_s = check_number(max_dt_s, "max_dt_s", low=0.0)
        self._factory = reader_factory or _default_reader
        self.track = open_trajectory(self.trajectory)
        reader = self._open()
        try:
            meta = reader.metadata
            pin = meta.intrinsics
            K = np.asarray(pin.intrinsic_matrix, np.float64)
            self.metadata = {k: _plain(getattr(meta, k, None)) for k in ("device_name", "serial_number", "color_format",
                                                                             "depth_format", "fps", "width", "height",
                                                                             "stream_length_usec", "depth_scale")}
        finally:
            reader.close()
        fmt = str(self.metadata["color_format"] or "RGB8")
        if fmt not in _COLOUR_ORDER:
            raise LogFormatError(f"{self.path}: colour stream format {fmt!r} not read (expected one of "
                                 f"{', '.join(_COLOUR_ORDER)})")
        if str(self.metadata["depth_format"] or "Z16") != "Z16":
            raise LogFormatError(f"{self.path}: depth stream format {self.metadata['depth_format']!r} not read (expected Z16)")
        self._order = _COLOUR_ORDER[fmt]
        if intrinsics is None:
            self.intrinsics = Intrinsics(int(pin.width), int(pin.height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                                         float(K[1, 2]))
            self.intrinsics_source = ("bag", "the colour stream's intrinsics in the bag (depth is aligned to colour)")
        elif isinstance(intrinsics, Intrinsics):
            self.intrinsics, self.intrinsics_source = intrinsics, ("given", "given by the caller")
        else:
            raise InvalidInputError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
        bag_scale = float(self.metadata["depth_scale"] or 0.0)
        if depth_scale is not None:
            self.depth_scale = check_number(depth_scale, "depth_scale", low=0.0, low_open=True)
            self.depth_scale_source = "given"
        elif bag_scale > 0:
            self.depth_scale, self.depth_scale_source = bag_scale, "the bag's metadata"
        else:
            self.depth_scale = D400_DEPTH_SCALE
            self.depth_scale_source = ("the bag's metadata holds none: the D400 series' 1 mm units assumed "
                                       "(--depth-scale to change; L515: 4000)")
        fps = float(self.metadata["fps"] or 30.0)
        self.fps = fps if fps > 0 else 30.0
        self.calibration = Calibration("kinect", self.intrinsics, self.intrinsics, RigidTransform.identity("colour", "depth"),
                                       self.fps, self.fps)
        self.skipped: Counter = Counter()

    def _open(self):
        reader = self._factory()
        if not reader.open(str(self.path)):
            raise LogFormatError(f"{self.path}: Open3D's RSBagReader could not open the bag (not a RealSense recording, "
                                 "or its colour or depth stream is missing)")
        return reader

    def __len__(self) -> int:
        """Frames expected from the recording's length and frame rate (for progress bars)."""
        length = float(self.metadata["stream_length_usec"] or 0)
        return max(int(round(length * 1e-6 * self.fps)), 0)

    def frames(self) -> Iterator[TumFrame]:
        """The frames with a pose, in recording order (those without are counted in :attr:`skipped`)."""
        self.skipped.pop("no_pose", None)  # counted afresh per pass
        max_dt_ns = round(self.max_dt_s * 1e9)
        h, w = self.intrinsics.shape
        reader = self._open()
        try:
            index = 0
            while not reader.is_eof():
                im = reader.next_frame()
                depth = _array(im.depth)
                if depth.size == 0:  # the empty image at the end
                    break
                colour = _array(im.color)
                ns = int(reader.get_timestamp()) * 1000
                where = f"{self.path}, frame {index} ({ns / 1e9:.6f} s)"
                if depth.ndim == 3 and depth.shape[2] == 1:
                    depth = depth[:, :, 0]
                if depth.dtype != np.uint16 or depth.shape != (h, w):
                    raise LogFormatError(f"{where}: expected {h}×{w} 16-bit depth, got {depth.dtype} {depth.shape}")
                if colour.dtype != np.uint8 or colour.ndim != 3 or colour.shape[:2] != (h, w) or colour.shape[2] < 3:
                    raise LogFormatError(f"{where}: expected {h}×{w} 8-bit colour, got {colour.dtype} {colour.shape}")
                pose = self.track.pose_at(ns, max_dt_ns, "nearest", index=index)
                index += 1
                if pose is None:
                    self.skipped["no_pose"] += 1
                    continue
                rgb = np.ascontiguousarray(colour[:, :, list(self._order)])
                known = depth > 0
                depth_m = (depth / self.depth_scale).astype(np.float32)
                yield TumFrame(ns, rgb, depth_m, known, pose[0])
        finally:
            reader.close()

    def __iter__(self) -> Iterator[TumFrame]:
        return self.frames()


def _plain(value):
    if isinstance(value, (str, int, float)) or value is None:
        return value
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


def read_realsense_bag(path: str | Path, *, trajectory: str | Path | None = None, intrinsics: Intrinsics | None = None,
                       depth_scale: float | None = None, max_dt_s: float = 0.02,
                       reader_factory: Callable | None = None) -> RealSenseBag:
    """Open a RealSense ``.bag`` (or the folder holding one) with the camera poses of ``trajectory``.

    Args:
        path: the ``.bag`` file, or a folder with exactly one.
        trajectory: the pose file (required: a bag holds no poses): ``.log`` by frame number, or TUM
            format by the time in the recording.
        intrinsics: overrides the bag's colour intrinsics.
        depth_scale: depth units per metre (> 0); None: the bag's, else :data:`D400_DEPTH_SCALE`.
        max_dt_s: for a TUM-format trajectory: largest |time difference| to the nearest pose.
        reader_factory: makes the reader (default ``open3d.t.io.RSBagReader``); for tests.

    Raises:
        LogFormatError: no bag, no trajectory (naming ``--poses FILE``), a bag the reader cannot open, a
            malformed trajectory, or a frame of another size or format.
    """
    bag = find_bag(path)
    if bag is None:
        raise LogFormatError(f"{path}: not a .bag file or a folder holding exactly one")
    if trajectory is None:
        raise LogFormatError(f"{bag}: a RealSense bag holds no camera poses; give a trajectory with --poses FILE (the .log "
                             "format, one 4×4 pose per frame, or TUM format by the time in the recording; Python: "
                             "poses=FILE)")
    return RealSenseBag(bag, Path(trajectory), intrinsics=intrinsics, depth_scale=depth_scale, max_dt_s=max_dt_s,
                        reader_factory=reader_factory)
