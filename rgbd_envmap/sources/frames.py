"""One protocol over every recording ``replay`` reads: what the pipeline needs from a source.

A :class:`FrameSource` has

- ``calibration``: the :class:`~rgbd_envmap.types.Calibration` the pipeline runs with;
- ``kind``: ``"tango"`` (it yields :class:`~rgbd_envmap.types.DepthPacket` /
  :class:`~rgbd_envmap.types.ColourPacket` for :meth:`Pipeline.feed`) or ``"rgbd"`` (it yields
  registered RGB-D frames, :class:`~rgbd_envmap.tum.TumFrame`, for :meth:`Pipeline.feed_rgbd`):
  every reader of either kind yields these same objects, and :func:`feed` is the one way they enter
  a pipeline;
- ``default_origin()``: the EM origin when none is given (a session log or a phone capture: its true
  map's origin if it has one, else 1 m along the first colour camera's optical axis; an RGB-D
  recording: 1 m along the first readable frame's axis);
- ``truth()``: the true map stored beside the recording (``groundtruth/envmap.npz``: ``radiance``,
  ``distance_m``, ``valid``, ``origin``) or None;
- ``skipped``: a :class:`collections.Counter` of what iteration passed over (unreadable packet files,
  frames the association dropped, frames without a pose), filled while iterating;
- iteration: the items in delivery order; ``len()``: how many when every file is readable.

The adapters here also have what a run folder records (used by ``rgbd-envmap replay``, optional for
a source of your own): ``layout`` and ``description`` (words), ``with_truth()`` (the items paired
with their per-item ground truth dicts, ``{}`` where none), ``info()`` (the layout's settings for
``run.json``), ``skipped_files`` (the error of each skipped file) and ``warnings``. With ``strict``
the first unreadable item raises instead of being skipped.

Adapters: :class:`SessionLogSource` (:class:`~rgbd_envmap.logs.SessionLog`), :class:`RgbdSequenceSource`
(:class:`~rgbd_envmap.tum.TumSequence`: TUM RGB-D, ICL-NUIM, Redwood), :class:`StrayCaptureSource`
(:class:`~rgbd_envmap.sources.stray.StrayCapture`), :class:`RealSenseSource`
(:class:`~rgbd_envmap.sources.realsense.RealSenseBag`). :func:`open_source` recognises a folder's
layout (:data:`SOURCE_LAYOUTS`, tried in order) and opens it with :class:`SourceOptions`;
:func:`as_source` also wraps an already-open reader.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.sources.options import OPTION_FLAGS, SourceOptions
from rgbd_envmap.types import Calibration, ColourPacket, DepthPacket

__all__ = ["FrameSource", "SessionLogSource", "RgbdSequenceSource", "StrayCaptureSource", "RealSenseSource",
           "SourceLayout", "SourceOptions", "SOURCE_LAYOUTS", "detect_source_layout", "open_source", "as_source",
           "read_truth", "feed", "layout_named", "layouts_text", "check_options"]

#: skipped-file messages kept per source (the count in ``skipped`` is always complete).
_MAX_MESSAGES = 1000


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


def feed(pipe, item):
    """Feed one item of a :class:`FrameSource` to a :class:`~rgbd_envmap.pipeline.Pipeline`: a packet
    through :meth:`~rgbd_envmap.pipeline.Pipeline.feed`, a registered RGB-D frame (``timestamp_ns``,
    ``rgb``, ``depth_m``, ``known``, ``T_world_from_cam``) through
    :meth:`~rgbd_envmap.pipeline.Pipeline.feed_rgbd`. Returns what the pipeline returns."""
    if isinstance(item, (DepthPacket, ColourPacket)):
        return pipe.feed(item)
    return pipe.feed_rgbd(item.timestamp_ns, item.rgb, item.depth_m, item.known, item.T_world_from_cam)


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


class _Recorded:
    """What every adapter here shares: skip counts, their messages, warnings, strictness."""

    layout = ""
    description: str | None = None

    def _init(self, root: Path, strict: bool, skipped: Counter | None = None) -> None:
        self.root = Path(root)
        self.strict = bool(strict)
        self.skipped: Counter = Counter() if skipped is None else skipped
        self.skipped_files: list[str] = []
        self.warnings: list[str] = []

    def _skip(self, kind: str, exc: LogFormatError) -> None:
        """Count ``exc`` under ``kind``, or raise it when strict."""
        if self.strict:
            raise exc
        self.skipped[kind] += 1
        if len(self.skipped_files) < _MAX_MESSAGES:
            self.skipped_files.append(str(exc))

    def truth(self) -> dict | None:
        return read_truth(self.root / "groundtruth" / "envmap.npz")

    def info(self) -> dict:
        return {"layout": self.layout}

    def __iter__(self) -> Iterator:
        for item, _ in self._items(False):
            yield item

    def with_truth(self) -> Iterator[tuple[object, dict]]:
        """(item, its ground truth arrays or {}) in delivery order."""
        return self._items(True)

    def _items(self, truth: bool) -> Iterator[tuple[object, dict]]:
        raise NotImplementedError


class SessionLogSource(_Recorded):
    """A session log written by ``simulate`` (packets read lazily; unreadable ones counted under
    ``skipped["depth"]`` / ``skipped["colour"]``, unreadable per-packet truth under
    ``skipped["depth_groundtruth"]`` / ``["colour_groundtruth"]``)."""

    kind = "tango"
    layout = "session log"

    def __init__(self, log, *, strict: bool = False) -> None:
        self._init(log.root, strict)
        self.log = log
        self.calibration = log.calibration
        self.warnings = list(log.warnings)

    def __len__(self) -> int:
        return len(self.log)

    def default_origin(self) -> np.ndarray:
        gt = self.truth()
        if gt is not None and "origin" in gt:
            return np.asarray(gt["origin"], np.float64)
        if not len(self.log.colour_timestamps_ns):
            raise LogFormatError(f"{self.log.root}: the log has no colour frames")
        return _ahead(self.log.read_colour(0).T_world_from_colour)

    def info(self) -> dict:
        return {"layout": self.layout, "dropped_points": dict(self.log.dropped_points), "warnings": list(self.log.warnings)}

    def _items(self, truth: bool) -> Iterator[tuple[object, dict]]:
        for kind, i, ns in self.log.entries():
            try:
                packet = self.log.read_depth(i, strict=self.strict) if kind == "depth" else self.log.read_colour(i)
            except LogFormatError as exc:
                self._skip(kind, exc)
                continue
            gt: dict = {}
            if truth:
                try:
                    gt = self.log.groundtruth(kind, ns)
                except LogFormatError as exc:  # never fatal: the packet itself is fine
                    self.skipped[f"{kind}_groundtruth"] += 1
                    self.skipped_files.append(str(exc))
            yield packet, gt


def _sequence_info(seq) -> dict:
    name, reason = seq.intrinsics_source
    out = {
        "intrinsics": {"source": name, "reason": reason, **seq.intrinsics.to_dict()},
        "depth_scale_units_per_m": seq.depth_scale,
        "depth_correction": seq.depth_correction,
        "poses_file": str(seq.trajectory),
        "pose_association": {"max_dt_s": seq.max_dt_s, "method": seq.poses},
    }
    camera = getattr(seq, "depth_correction_camera", None)
    if camera is not None:
        out["depth_correction_camera"] = camera
    return out


class RgbdSequenceSource(_Recorded):
    """A registered RGB-D sequence (:class:`~rgbd_envmap.tum.TumSequence`: TUM RGB-D, ICL-NUIM,
    Redwood) for the Kinect path. ``skipped`` starts with the association's drops
    (``association_no_rgb``, ``association_no_pose`` …) and counts unreadable frames under ``frame``;
    per-frame truth is ``groundtruth/frames/<timestamp_ns>.npz`` when present."""

    kind = "rgbd"

    def __init__(self, seq, *, strict: bool = False, layout: str | None = None) -> None:
        self._init(seq.root, strict, Counter({f"association_{k}": v for k, v in seq.skipped.items() if v}))
        self.seq = seq
        self.calibration = seq.pipeline_calibration
        self.layout = layout or getattr(seq, "layout", None) or (
            "ICL-NUIM" if seq.index_names and seq.index_names[0] == "associations.txt" else "TUM RGB-D")
        self.description = f"{self.layout}, Kinect path"

    def __len__(self) -> int:
        return len(self.seq)

    def default_origin(self) -> np.ndarray:
        for i in range(len(self.seq)):
            try:
                return _ahead(self.seq.load(i).T_world_from_cam)
            except LogFormatError:
                if self.strict:
                    raise
        raise LogFormatError(f"{self.seq.root}: no frame of the sequence could be read")

    def info(self) -> dict:
        return {"layout": self.layout, **_sequence_info(self.seq)}

    def _items(self, truth: bool) -> Iterator[tuple[object, dict]]:
        truth_dir = self.root / "groundtruth" / "frames"
        for i in range(len(self.seq)):
            try:
                f = self.seq.load(i)
            except LogFormatError as exc:
                self._skip("frame", exc)
                continue
            gt: dict = {}
            if truth:
                gt = read_truth(truth_dir / f"{f.timestamp_ns}.npz") or {}
            yield f, gt


class StrayCaptureSource(_Recorded):
    """A phone capture in the Stray Scanner layout (:class:`~rgbd_envmap.sources.stray.StrayCapture`)
    for the mobile path; an unreadable depth image is counted under ``skipped["depth"]``, a video that
    stops decoding ends the stream (``skipped["colour"]``), unreadable per-frame truth
    (``groundtruth/frames/NNNNNN.npz``) under ``skipped["groundtruth"]``."""

    kind = "tango"
    layout = "phone (Stray Scanner)"
    description = "phone capture, Stray Scanner layout, mobile path"

    def __init__(self, capture, *, strict: bool = False) -> None:
        self._init(capture.root, strict)
        self.capture = capture
        self.calibration = capture.calibration

    def __len__(self) -> int:
        return len(self.capture)

    def default_origin(self) -> np.ndarray:
        gt = self.truth()
        if gt is not None and "origin" in gt:
            return np.asarray(gt["origin"], np.float64)
        if not self.capture.frames:
            raise LogFormatError(f"{self.capture.root}: the capture has no frames")
        return _ahead(self.capture.frames[0].T_world_from_cam)

    def info(self) -> dict:
        from rgbd_envmap.sources.stray import CONFIDENCE_VALUES

        cap = self.capture
        return {"layout": self.layout, "phone": {
            "video_size": list(cap.video_size), "colour_size": list(cap.colour_size),
            "depth_size": [cap.calibration.depth.width, cap.calibration.depth.height],
            "frames": len(cap.frames), "depth_frames_taken": len(cap.depth_frames), "depth_rate_hz": cap.depth_rate_hz,
            "confidence_values": list(CONFIDENCE_VALUES), "has_confidence": cap.has_confidence,
            "not_fed": {k: v for k, v in cap.skipped.items() if v},
        }}

    def _items(self, truth: bool) -> Iterator[tuple[object, dict]]:
        truth_dir = self.root / "groundtruth" / "frames"
        cached: dict[int, dict] = {}

        def frame_truth(frame: int) -> dict:
            if frame not in cached:
                cached.clear()
                try:
                    cached[frame] = read_truth(truth_dir / f"{frame:06d}.npz") or {}
                except LogFormatError as exc:
                    self.skipped["groundtruth"] += 1
                    self.skipped_files.append(str(exc))
                    cached[frame] = {}
            return cached[frame]

        for packet, row in self.capture.packets(self._skip):
            yield packet, (frame_truth(row.frame) if truth else {})


class RealSenseSource(_Recorded):
    """A RealSense bag (:class:`~rgbd_envmap.sources.realsense.RealSenseBag`) for the Kinect path
    (depth aligned to colour); frames without a pose are counted under ``skipped["no_pose"]``."""

    kind = "rgbd"
    layout = "RealSense"
    description = "RealSense bag, Kinect path"

    def __init__(self, bag, *, strict: bool = False) -> None:
        self._init(bag.path.parent, strict, bag.skipped)
        self.bag = bag
        self.calibration = bag.calibration

    def __len__(self) -> int:
        return len(self.bag)

    def truth(self) -> dict | None:
        return None

    def default_origin(self) -> np.ndarray:
        frames = self.bag.frames()
        try:
            first = next(frames, None)
        finally:
            frames.close()
        if first is None:
            raise LogFormatError(f"{self.bag.path}: no frame of the bag has a pose in {self.bag.trajectory}")
        return _ahead(first.T_world_from_cam)

    def info(self) -> dict:
        b = self.bag
        name, reason = b.intrinsics_source
        return {"layout": self.layout, "bag": str(b.path), "realsense": dict(b.metadata),
                "intrinsics": {"source": name, "reason": reason, **b.intrinsics.to_dict()},
                "depth_scale_units_per_m": b.depth_scale, "depth_scale_source": b.depth_scale_source,
                "poses_file": str(b.trajectory), "pose_association": {"max_dt_s": b.max_dt_s, "method": "nearest"}}

    def _items(self, truth: bool) -> Iterator[tuple[object, dict]]:
        for f in self.bag.frames():
            yield f, {}


# --------------------------------------------------------------------------------------------------
# Layouts: recognising a folder and opening it
# --------------------------------------------------------------------------------------------------


def _camera(options: SourceOptions):
    return options.camera()


def _open_tum(root: Path, options: SourceOptions) -> RgbdSequenceSource:
    from rgbd_envmap.tum import TUM_DEPTH_CORRECTION, TUM_DEPTH_SCALE, read_tum_sequence, tum_camera_from_name

    if options.poses is None and not (root / "groundtruth.txt").is_file():
        raise LogFormatError(f"{root / 'groundtruth.txt'}: missing file (the benchmark's validation and test sequences "
                             "ship without ground truth: give an estimated trajectory with --poses FILE, TUM format or "
                             ".log; Python: poses=FILE)")
    given = _camera(options)
    seq = read_tum_sequence(root, intrinsics="auto" if given is None else given[0],
                            depth_scale=TUM_DEPTH_SCALE if options.depth_scale is None else options.depth_scale,
                            trajectory=options.poses)
    if given is not None:
        seq.intrinsics_source = (given[1][0], given[1][1] + (" (overrides calibration.json)"
                                                             if (root / "calibration.json").is_file() else ""))
    want = options.depth_correction
    if want is not None:
        if want == "auto":
            camera = seq.intrinsics_source[0]
            want = camera if camera in ("fr1", "fr2", "fr3") else tum_camera_from_name(seq.root)
            if want is None:
                raise InvalidInputError(f"--tum-depth-correction (depth_correction='auto'): neither the intrinsics in use "
                                        f"({camera}) nor the folder name {Path(seq.root).name!r} names a freiburg camera, so "
                                        "the factor is unknown; name the camera with --intrinsics fr1|fr2|fr3")
        seq.depth_correction, seq.depth_correction_camera = TUM_DEPTH_CORRECTION[want], want
    return _nonempty(RgbdSequenceSource(seq, strict=options.strict, layout="TUM RGB-D"))


def _nonempty(src: RgbdSequenceSource) -> RgbdSequenceSource:
    seq = src.seq
    if not len(seq):
        raise LogFormatError(f"{seq.root}: no frame has rgb, depth and a pose within the association window (skipped: "
                             f"{seq.skipped}; poses from {seq.trajectory})")
    return src


def _open_rgbd_folder(read, default_scale: float, layout: str, root: Path, options: SourceOptions) -> RgbdSequenceSource:
    """A registered RGB-D folder read by ``read`` (ICL-NUIM, Redwood), with the options' camera, scale and poses."""
    given = _camera(options)
    seq = read(root, intrinsics=None if given is None else given[0],
               depth_scale=default_scale if options.depth_scale is None else options.depth_scale, trajectory=options.poses)
    if given is not None:
        seq.intrinsics_source = given[1]
    return _nonempty(RgbdSequenceSource(seq, strict=options.strict, layout=layout))


def _open_icl(root: Path, options: SourceOptions) -> RgbdSequenceSource:
    from rgbd_envmap.icl import read_icl_nuim_sequence
    from rgbd_envmap.tum import TUM_DEPTH_SCALE

    return _open_rgbd_folder(read_icl_nuim_sequence, TUM_DEPTH_SCALE, "ICL-NUIM", root, options)


def _open_redwood(root: Path, options: SourceOptions) -> RgbdSequenceSource:
    from rgbd_envmap.sources.redwood import REDWOOD_DEPTH_SCALE, read_redwood_sequence

    return _open_rgbd_folder(read_redwood_sequence, REDWOOD_DEPTH_SCALE, "Redwood", root, options)


def _open_realsense(root: Path, options: SourceOptions) -> RealSenseSource:
    from rgbd_envmap.sources.realsense import read_realsense_bag

    given = _camera(options)
    bag = read_realsense_bag(root, trajectory=options.poses, intrinsics=None if given is None else given[0],
                             depth_scale=options.depth_scale)
    if given is not None:
        bag.intrinsics_source = given[1]
    return RealSenseSource(bag, strict=options.strict)


def _open_stray(root: Path, options: SourceOptions) -> StrayCaptureSource:
    from rgbd_envmap.sources.stray import read_stray_capture

    return StrayCaptureSource(read_stray_capture(root, depth_rate_hz=options.depth_rate_hz, colour_size=options.colour_size),
                              strict=options.strict)


def _open_session(root: Path, options: SourceOptions) -> SessionLogSource:
    from rgbd_envmap.logs import SessionLog

    return SessionLogSource(SessionLog.open(root), strict=options.strict)


def _is_tum(root: Path) -> bool:
    return root.is_dir() and (root / "rgb.txt").is_file() and (root / "depth.txt").is_file()


def _is_icl(root: Path) -> bool:
    from rgbd_envmap.icl import is_icl_nuim_sequence

    return root.is_dir() and is_icl_nuim_sequence(root)


def _is_stray(root: Path) -> bool:
    from rgbd_envmap.sources.stray import is_stray_capture

    return root.is_dir() and is_stray_capture(root)


def _is_redwood(root: Path) -> bool:
    from rgbd_envmap.sources.redwood import is_redwood_folder

    return is_redwood_folder(root)


def _is_realsense(root: Path) -> bool:
    from rgbd_envmap.sources.realsense import is_realsense_bag

    return is_realsense_bag(root)


def _is_session(root: Path) -> bool:
    return root.is_dir() and any((root / n).is_file()
                                 for n in ("calibration.json", "colour.txt", "colour_poses.txt", "depth_poses.txt"))


_SEQUENCE = frozenset({"intrinsics", "depth_scale", "poses"})


@dataclass(frozen=True)
class SourceLayout:
    """A recording layout :func:`open_source` reads.

    Attributes:
        name: shown in messages and ``run.json`` ("TUM RGB-D").
        files: the files that identify it, in words (for ``--help`` and the error on an unknown folder).
        recognise: path → whether it has this layout (looks at file names only).
        open: (path, :class:`SourceOptions`) → :class:`FrameSource`.
        takes: the :data:`~rgbd_envmap.sources.options.OPTION_FLAGS` fields that apply to it (a field
            given to a layout that does not take it is refused).
        poses: where its poses come from, in words (for ``--help``).
    """

    name: str
    files: str
    recognise: Callable[[Path], bool]
    open: Callable[[Path, SourceOptions], FrameSource]
    takes: frozenset = field(default_factory=frozenset)
    poses: str = ""


#: the layouts, tried in this order (a TUM folder written by ``simulate`` also holds a
#: calibration.json, so TUM RGB-D comes before the session log; TUM and ICL-NUIM folders have rgb/ and
#: depth/ too, so both come before Redwood).
SOURCE_LAYOUTS: tuple[SourceLayout, ...] = (
    SourceLayout("TUM RGB-D", "rgb.txt + depth.txt (+ groundtruth.txt, rgb/, depth/)", _is_tum, _open_tum,
                 _SEQUENCE | {"depth_correction"}, "groundtruth.txt, or --poses"),
    SourceLayout("ICL-NUIM", "associations.txt + one *.gt.freiburg (+ rgb/, depth/)", _is_icl, _open_icl, _SEQUENCE,
                 "the *.gt.freiburg file, or --poses"),
    SourceLayout("phone (Stray Scanner)", "odometry.csv + camera_matrix.csv + rgb.mp4 (+ depth/, confidence/)",
                 _is_stray, _open_stray, frozenset(), "odometry.csv (ARKit)"),
    SourceLayout("Redwood", "depth/ + colors/ | color/ | image/ | rgb/ (+ camera_intrinsic.json, *-traj.txt or "
                 "trajectory.log)", _is_redwood, _open_redwood, _SEQUENCE, "the *-traj.txt / trajectory.log file, or --poses"),
    SourceLayout("RealSense", "a .bag file (or a folder holding one), read by Open3D's RSBagReader", _is_realsense,
                 _open_realsense, _SEQUENCE, "none in the bag: --poses is required"),
    SourceLayout("session log", "calibration.json + depth.txt, colour.txt and their _poses.txt (written by simulate)",
                 _is_session, _open_session, frozenset(), "depth_poses.txt, colour_poses.txt"),
)


def layouts_text(layouts: tuple[SourceLayout, ...] = SOURCE_LAYOUTS) -> str:
    """The layouts as lines ``NAME: FILES; poses: WHERE`` (for ``--help``)."""
    return "\n".join(f"  {lay.name}: {lay.files}; poses: {lay.poses}" for lay in layouts)


def layout_named(name: str, layouts: tuple[SourceLayout, ...] = SOURCE_LAYOUTS) -> SourceLayout:
    """The layout called ``name`` (InvalidInputError listing the names otherwise)."""
    for lay in layouts:
        if lay.name == name:
            return lay
    raise InvalidInputError(f"layout: expected one of {[lay.name for lay in layouts]}, got {name!r}")


def _known(layouts) -> str:
    return "; ".join(f"{lay.name}: {lay.files}" for lay in layouts)


def _found(root: Path, limit: int = 12) -> str:
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in root.iterdir())
    if not names:
        return "nothing (empty folder)"
    return ", ".join(names[:limit]) + (f", … ({len(names) - limit} more)" if len(names) > limit else "")


def detect_source_layout(path: str | Path, layouts: tuple[SourceLayout, ...] = SOURCE_LAYOUTS) -> SourceLayout:
    """The first of ``layouts`` (default :data:`SOURCE_LAYOUTS`) that recognises ``path``.

    Raises:
        LogFormatError: no such path, a file no layout reads, or a folder no layout recognises (naming
            the layouts known and the files found).
    """
    root = Path(path)
    if root.is_dir() or root.is_file():
        for layout in layouts:
            if layout.recognise(root):
                return layout
    if not root.is_dir():
        raise LogFormatError(f"{root}: not a folder (the recordings read are folders, or a RealSense .bag file: "
                             f"{_known(layouts)})")
    raise LogFormatError(f"{root}: not a known recording layout ({_known(layouts)}); found {_found(root)}")


def check_options(layout: SourceLayout, options: SourceOptions, where: str | Path = "",
                  names: dict[str, str] | None = None) -> None:
    """Refuse the fields of ``options`` that do not apply to ``layout``, naming them by ``names``
    (default: the CLI's flags, :data:`~rgbd_envmap.sources.options.OPTION_FLAGS`) and the layouts that
    take them.

    Raises:
        InvalidInputError: a field given that ``layout`` does not take.
    """
    names = OPTION_FLAGS if names is None else names
    extra = [name for name in options.given() if name not in layout.takes]
    if extra:
        takers = [lay.name for lay in SOURCE_LAYOUTS if set(extra) <= lay.takes]
        raise InvalidInputError(f"{', '.join(names[n] for n in extra)}: appl{'ies' if len(extra) == 1 else 'y'} to "
                                f"{', '.join(takers) or 'no one layout'}, not to a recording of the {layout.name} layout"
                                + (f" ({where})" if where else ""))


def open_source(path: str | Path, options: SourceOptions | None = None, *, layout: SourceLayout | None = None,
                **fields) -> FrameSource:
    """Open the recording ``path`` (its layout detected, or ``layout``) with ``options`` (or the
    :class:`SourceOptions` fields given as keywords: ``open_source(bag, poses="traj.log")``). Defaults
    are ``rgbd-envmap replay``'s (TUM: intrinsics ``"auto"``; ICL-NUIM: its published intrinsics; both
    5000 depth units per metre; Redwood: ``camera_intrinsic.json`` or the PrimeSense default, 1000 per
    metre; RealSense: the bag's camera, a trajectory required; phone: depth at 5 Hz, video at its own
    size).

    Raises:
        LogFormatError: :func:`detect_source_layout`'s, a recording without poses (naming ``--poses
            FILE``), and the reader's.
        InvalidInputError: an option that does not apply to the layout, or a bad option.
    """
    if options is None:
        options = SourceOptions(**fields)
    elif fields:
        raise InvalidInputError(f"open_source: give options or keywords, not both (got options and {sorted(fields)})")
    elif not isinstance(options, SourceOptions):
        raise InvalidInputError(f"options: expected a SourceOptions, got {type(options).__name__}")
    root = Path(path)
    lay = detect_source_layout(root) if layout is None else layout
    check_options(lay, options, root, names={n: n for n in OPTION_FLAGS} if fields else None)
    return lay.open(root, options)


def as_source(source, **fields) -> FrameSource:
    """A :class:`FrameSource` from a recording path (opened by :func:`open_source` with ``fields``), an
    open :class:`~rgbd_envmap.logs.SessionLog`, :class:`~rgbd_envmap.tum.TumSequence`,
    :class:`~rgbd_envmap.sources.stray.StrayCapture` or :class:`~rgbd_envmap.sources.realsense.RealSenseBag`,
    or a :class:`FrameSource` already (returned as is)."""
    if isinstance(source, (str, Path)):
        return open_source(source, **fields)
    if fields:
        raise InvalidInputError(f"{', '.join(sorted(fields))}: apply when source is a path, not a {type(source).__name__}")
    from rgbd_envmap.logs import SessionLog
    from rgbd_envmap.sources.realsense import RealSenseBag
    from rgbd_envmap.sources.stray import StrayCapture
    from rgbd_envmap.tum import TumSequence

    if isinstance(source, SessionLog):
        return SessionLogSource(source)
    if isinstance(source, TumSequence):
        return RgbdSequenceSource(source)
    if isinstance(source, StrayCapture):
        return StrayCaptureSource(source)
    if isinstance(source, RealSenseBag):
        return RealSenseSource(source)
    if isinstance(source, FrameSource) and getattr(source, "kind", None) in ("tango", "rgbd"):
        return source
    raise InvalidInputError(f"source: expected a recording path, a SessionLog, TumSequence, StrayCapture, RealSenseBag or a "
                            f"FrameSource (calibration, kind 'tango' | 'rgbd', default_origin(), truth(), skipped, "
                            f"iteration), got {type(source).__name__}")
