"""One protocol over every recording ``replay`` reads: what the pipeline needs from a source.

A :class:`FrameSource` has

- ``calibration``: the :class:`~rgbd_envmap.types.Calibration` the pipeline runs with;
- ``kind``: ``"tango"`` (it yields :class:`~rgbd_envmap.types.DepthPacket` /
  :class:`~rgbd_envmap.types.ColourPacket` for :meth:`Pipeline.feed`) or ``"rgbd"`` (it yields
  registered :class:`~rgbd_envmap.tum.TumFrame` s for :meth:`Pipeline.feed_rgbd`);
- ``default_origin()``: the EM origin when none is given, chosen as ``rgbd-envmap replay`` chooses it
  (a session log or a phone capture: its true map's origin if it has one, else 1 m along the first
  colour camera's optical axis; an RGB-D sequence: 1 m along the first readable frame's axis);
- ``truth()``: the true map stored beside the recording (``groundtruth/envmap.npz``: ``radiance``,
  ``distance_m``, ``valid``, ``origin``) or None;
- ``skipped``: a :class:`collections.Counter` of what iteration passed over (unreadable packet files,
  frames the association dropped), filled while iterating;
- iteration: the items in delivery order; ``len()``: how many when every file is readable.

Adapters: :class:`SessionLogSource` (:class:`~rgbd_envmap.logs.SessionLog`), :class:`RgbdSequenceSource`
(:class:`~rgbd_envmap.tum.TumSequence`: TUM RGB-D and ICL-NUIM), :class:`StrayCaptureSource`
(:class:`~rgbd_envmap.sources.stray.StrayCapture`). :func:`open_source` recognises a folder's layout
(:data:`SOURCE_LAYOUTS`, in the order the CLI tries them) and opens it with the CLI's defaults;
:func:`as_source` also wraps an already-open reader.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.types import Calibration

__all__ = ["FrameSource", "SessionLogSource", "RgbdSequenceSource", "StrayCaptureSource", "SourceLayout",
           "SOURCE_LAYOUTS", "detect_source_layout", "open_source", "as_source", "read_truth"]


@runtime_checkable
class FrameSource(Protocol):
    """What :func:`rgbd_envmap.replay` reads (module docstring)."""

    calibration: Calibration
    kind: str
    skipped: Counter

    def default_origin(self) -> np.ndarray: ...

    def truth(self) -> dict | None: ...

    def __iter__(self) -> Iterator: ...

    def __len__(self) -> int: ...


def read_truth(path: Path) -> dict | None:
    """The arrays of the NPZ ``path`` as a dict, or None if there is no such file."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError) as exc:
        raise LogFormatError(f"{path}: unreadable NPZ ({exc})") from None


def _ahead(T) -> np.ndarray:
    return T.translation + T.rotation[:, 2]


class SessionLogSource:
    """A session log written by ``simulate`` (packets read lazily; unreadable ones counted under
    ``skipped["depth"]`` / ``skipped["colour"]``)."""

    kind = "tango"

    def __init__(self, log) -> None:
        self.log = log
        self.calibration = log.calibration
        self.skipped: Counter = Counter()

    def __len__(self) -> int:
        return len(self.log)

    def truth(self) -> dict | None:
        return read_truth(self.log.root / "groundtruth" / "envmap.npz")

    def default_origin(self) -> np.ndarray:
        gt = self.truth()
        if gt is not None and "origin" in gt:
            return np.asarray(gt["origin"], np.float64)
        if not len(self.log.colour_timestamps_ns):
            raise LogFormatError(f"{self.log.root}: the log has no colour frames")
        return _ahead(self.log.read_colour(0).T_world_from_colour)

    def __iter__(self) -> Iterator:
        for kind, i, _ in self.log.entries():
            try:
                yield self.log.read_depth(i) if kind == "depth" else self.log.read_colour(i)
            except LogFormatError:
                self.skipped[kind] += 1


class RgbdSequenceSource:
    """A TUM RGB-D or ICL-NUIM sequence (:class:`~rgbd_envmap.tum.TumSequence`) for the Kinect path.
    ``skipped`` starts with the association's drops (``association_no_rgb`` …) and counts unreadable
    frames under ``frame``."""

    kind = "rgbd"

    def __init__(self, seq) -> None:
        self.seq = seq
        self.calibration = seq.pipeline_calibration
        self.skipped: Counter = Counter({f"association_{k}": v for k, v in seq.skipped.items() if v})

    def __len__(self) -> int:
        return len(self.seq)

    def truth(self) -> dict | None:
        return read_truth(Path(self.seq.root) / "groundtruth" / "envmap.npz")

    def default_origin(self) -> np.ndarray:
        for i in range(len(self.seq)):
            try:
                return _ahead(self.seq.load(i).T_world_from_cam)
            except LogFormatError:
                continue
        raise LogFormatError(f"{self.seq.root}: no frame of the sequence could be read")

    def __iter__(self) -> Iterator:
        for i in range(len(self.seq)):
            try:
                yield self.seq.load(i)
            except LogFormatError:
                self.skipped["frame"] += 1


class StrayCaptureSource:
    """A phone capture in the Stray Scanner layout (:class:`~rgbd_envmap.sources.stray.StrayCapture`)
    for the mobile path; an unreadable depth image is counted under ``skipped["depth"]``, a video that
    stops decoding ends the stream (``skipped["colour"]``)."""

    kind = "tango"

    def __init__(self, capture) -> None:
        self.capture = capture
        self.calibration = capture.calibration
        self.skipped: Counter = Counter()

    def __len__(self) -> int:
        return len(self.capture)

    def truth(self) -> dict | None:
        return read_truth(Path(self.capture.root) / "groundtruth" / "envmap.npz")

    def default_origin(self) -> np.ndarray:
        gt = self.truth()
        if gt is not None and "origin" in gt:
            return np.asarray(gt["origin"], np.float64)
        if not self.capture.frames:
            raise LogFormatError(f"{self.capture.root}: the capture has no frames")
        return _ahead(self.capture.frames[0].T_world_from_cam)

    def __iter__(self) -> Iterator:
        def on_error(kind: str, exc: LogFormatError) -> None:
            self.skipped[kind] += 1

        for packet, _ in self.capture.packets(on_error):
            yield packet


def _open_tum(root: Path) -> RgbdSequenceSource:
    from rgbd_envmap.tum import read_tum_sequence

    if not (root / "groundtruth.txt").is_file():
        raise LogFormatError(f"{root / 'groundtruth.txt'}: missing file (the benchmark's validation and test sequences "
                             "ship without ground truth: open it with rgbd_envmap.tum.read_tum_sequence(..., trajectory=FILE) "
                             "and pass the sequence)")
    return RgbdSequenceSource(read_tum_sequence(root, intrinsics="auto"))


def _open_icl(root: Path) -> RgbdSequenceSource:
    from rgbd_envmap.icl import read_icl_nuim_sequence

    return RgbdSequenceSource(read_icl_nuim_sequence(root))


def _open_stray(root: Path) -> StrayCaptureSource:
    from rgbd_envmap.sources.stray import read_stray_capture

    return StrayCaptureSource(read_stray_capture(root))


def _open_session(root: Path) -> SessionLogSource:
    from rgbd_envmap.logs import SessionLog

    return SessionLogSource(SessionLog.open(root))


def _is_tum(root: Path) -> bool:
    return (root / "rgb.txt").is_file() and (root / "depth.txt").is_file()


def _is_icl(root: Path) -> bool:
    from rgbd_envmap.icl import is_icl_nuim_sequence

    return is_icl_nuim_sequence(root)


def _is_stray(root: Path) -> bool:
    from rgbd_envmap.sources.stray import is_stray_capture

    return is_stray_capture(root)


def _is_session(root: Path) -> bool:
    return any((root / n).is_file() for n in ("calibration.json", "colour.txt", "colour_poses.txt", "depth_poses.txt"))


@dataclass(frozen=True)
class SourceLayout:
    """A folder layout :func:`open_source` reads: ``name``, the identifying ``files`` in words, and
    ``recognise`` / ``open`` (folder → bool / → :class:`FrameSource`)."""

    name: str
    files: str
    recognise: Callable[[Path], bool]
    open: Callable[[Path], FrameSource]


#: the layouts, tried in this order (the CLI's: a TUM folder written by ``simulate`` also holds a
#: calibration.json, so TUM RGB-D comes before the session log).
SOURCE_LAYOUTS: tuple[SourceLayout, ...] = (
    SourceLayout("TUM RGB-D", "rgb.txt + depth.txt (+ groundtruth.txt, rgb/, depth/)", _is_tum, _open_tum),
    SourceLayout("ICL-NUIM", "associations.txt + one *.gt.freiburg (+ rgb/, depth/)", _is_icl, _open_icl),
    SourceLayout("phone (Stray Scanner)", "odometry.csv + camera_matrix.csv + rgb.mp4 (+ depth/, confidence/)",
                 _is_stray, _open_stray),
    SourceLayout("session log", "calibration.json + depth.txt, colour.txt and their _poses.txt (written by simulate)",
                 _is_session, _open_session),
)


def _known() -> str:
    return "; ".join(f"{lay.name}: {lay.files}" for lay in SOURCE_LAYOUTS)


def _found(root: Path, limit: int = 12) -> str:
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in root.iterdir())
    if not names:
        return "nothing (empty folder)"
    return ", ".join(names[:limit]) + (f", … ({len(names) - limit} more)" if len(names) > limit else "")


def detect_source_layout(path: str | Path) -> SourceLayout:
    """The first of :data:`SOURCE_LAYOUTS` that recognises the folder ``path``.

    Raises:
        LogFormatError: not a folder, or no layout recognises it (naming the layouts known and the
            files found).
    """
    root = Path(path)
    if not root.is_dir():
        raise LogFormatError(f"{root}: not a folder (the recordings read are folders: {_known()})")
    for layout in SOURCE_LAYOUTS:
        if layout.recognise(root):
            return layout
    raise LogFormatError(f"{root}: not a known recording layout ({_known()}); found {_found(root)}")


def open_source(path: str | Path) -> FrameSource:
    """Open the recording folder ``path`` with the defaults of ``rgbd-envmap replay`` (TUM: intrinsics
    ``"auto"``; ICL-NUIM: its published intrinsics; both 5000 depth units per metre; phone: depth at
    5 Hz, video at its own size). For other settings open the reader yourself and pass it to
    :func:`as_source`. Errors: :func:`detect_source_layout`'s, and the reader's."""
    root = Path(path)
    return detect_source_layout(root).open(root)


def as_source(source) -> FrameSource:
    """A :class:`FrameSource` from a folder path, an open :class:`~rgbd_envmap.logs.SessionLog`,
    :class:`~rgbd_envmap.tum.TumSequence` or :class:`~rgbd_envmap.sources.stray.StrayCapture`, or a
    :class:`FrameSource` already (returned as is)."""
    if isinstance(source, (str, Path)):
        return open_source(source)
    from rgbd_envmap.logs import SessionLog
    from rgbd_envmap.sources.stray import StrayCapture
    from rgbd_envmap.tum import TumSequence

    if isinstance(source, SessionLog):
        return SessionLogSource(source)
    if isinstance(source, TumSequence):
        return RgbdSequenceSource(source)
    if isinstance(source, StrayCapture):
        return StrayCaptureSource(source)
    if isinstance(source, FrameSource) and getattr(source, "kind", None) in ("tango", "rgbd"):
        return source
    raise InvalidInputError(f"source: expected a recording folder, a SessionLog, TumSequence, StrayCapture or a FrameSource "
                            f"(calibration, kind 'tango' | 'rgbd', default_origin(), truth(), skipped, iteration), "
                            f"got {type(source).__name__}")
