"""``rgbd-envmap replay``: run the pipeline on a recorded sequence, no simulator involved.

The folder's layout is recognised by the files in it, in the order of :data:`LAYOUTS` (a table: add a
:class:`Layout` to read another kind of recording):

- **TUM RGB-D** (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``rgb/``, ``depth/``), as the public
  benchmark ships it or as ``simulate --device kinect`` writes it (with a ``calibration.json``);
  replayed through the Kinect path (warp + merge) with no conversion step
  (:func:`rgbd_envmap.tum.read_tum_sequence`). Intrinsics: ``--intrinsics`` if given, else
  ``calibration.json``, else the benchmark's calibration of the camera the folder's name names
  (``rgbd_dataset_freiburg1_*`` → ``fr1``), else the ROS default; ``run.json`` says which and why.
- **ICL-NUIM** in its TUM-compatible layout (``associations.txt``, one ``*.gt.freiburg``, ``rgb/``,
  ``depth/``; :func:`rgbd_envmap.icl.read_icl_nuim_sequence`), with the dataset's published intrinsics
  (fy < 0) unless ``--intrinsics`` is given; the Kinect path too.
- **Session log** of this project (``calibration.json``, ``depth.txt`` / ``colour.txt`` and their
  poses, as ``simulate`` writes it; :class:`rgbd_envmap.logs.SessionLog`), read packet by packet.

A folder that matches none fails with one line listing the layouts and the files found.

A session log's ground truth stored beside it (``groundtruth/``) feeds the accuracy report when
present. The EM origin is ``--origin`` if given, else the origin of the log's true map
(``groundtruth/envmap.npz``, written by ``simulate``), else 1 m in front of the first colour frame's
camera (for an RGB-D sequence: of the first readable frame's camera).

Corrupt data never builds a map silently: a packet file that cannot be read (truncated PNG, broken
PLY, NaN points) is skipped and counted under ``skipped`` in ``run.json`` and the report, with the
file named, unless ``strict`` is set, in which case the error (naming the file and line) ends the run.
Index-level problems (missing files, unsorted timestamps, NaN poses) fail when the log is opened.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from apps.phone import is_phone_capture, run_replay_phone
from apps.run import RunOptions, run_pipeline
from rgbd_envmap.errors import InvalidInputError, LogFormatError, RgbdEnvmapError
from rgbd_envmap.logs import SessionLog
from rgbd_envmap.pipeline import Pipeline, PipelineConfig
from rgbd_envmap.sources.frames import read_truth

__all__ = ["ReplayOptions", "Layout", "LAYOUTS", "INTRINSICS_PRESETS", "detect_layout", "run_replay", "run_replay_tum",
           "run_replay_icl", "run_replay_session", "default_origin", "is_tum_sequence", "is_session_log"]


@dataclass(frozen=True)
class ReplayOptions:
    """What ``replay`` was asked. ``intrinsics``, ``depth_scale``, ``poses`` and
    ``tum_depth_correction`` apply to RGB-D sequences (TUM RGB-D, ICL-NUIM) only; None: the layout's
    own (``depth_scale``: 5000 units per metre)."""

    log: Path
    out: Path
    origin: tuple[float, float, float] | None = None
    config: PipelineConfig = PipelineConfig()
    composite_every: int = 30
    video: bool = True
    progress: bool = True
    strict: bool = False
    rerun: Path | None = None
    cache_dir: Path | None = None
    #: a preset name (:data:`INTRINSICS_PRESETS`) or the path of a JSON file in ``Intrinsics.to_dict()`` form.
    intrinsics: str | None = None
    depth_scale: float | None = None
    #: a TUM-format trajectory file used instead of the sequence's own poses.
    poses: Path | None = None
    #: None: off; ``"auto"``: the factor of the freiburg camera in use; ``"fr1"`` / ``"fr2"`` / ``"fr3"``.
    tum_depth_correction: str | None = None


@dataclass(frozen=True)
class Layout:
    """A folder layout that ``replay`` reads.

    Attributes:
        name: shown in messages and ``run.json`` ("TUM RGB-D").
        files: the files that identify it, in words (for the error on an unknown folder).
        recognise: folder → whether it has this layout (looks at file names only).
        replay: runs the pipeline on such a folder and returns the run summary.
        sequence_options: whether it takes ``--intrinsics``, ``--depth-scale`` and ``--poses``.
    """

    name: str
    files: str
    recognise: Callable[[Path], bool]
    replay: Callable[[ReplayOptions], dict]
    sequence_options: bool = False


def _groundtruth_envmap(log: SessionLog) -> dict | None:
    return read_truth(log.root / "groundtruth" / "envmap.npz")


def default_origin(log: SessionLog) -> np.ndarray:
    """The true map's origin if the log has one, else 1 m along the first colour camera's optical axis."""
    gt = _groundtruth_envmap(log)
    if gt is not None and "origin" in gt:
        return np.asarray(gt["origin"], np.float64)
    if not len(log.colour_timestamps_ns):
        raise LogFormatError(f"{log.root}: the log has no colour frames")
    T = log.read_colour(0).T_world_from_colour
    return T.translation + T.rotation[:, 2]


def is_tum_sequence(path: Path) -> bool:
    """True for a folder in the public TUM RGB-D layout."""
    path = Path(path)
    return (path / "rgb.txt").is_file() and (path / "depth.txt").is_file()


def is_session_log(path: Path) -> bool:
    """True for a folder with any file of this project's session log (a broken log is then reported by
    :meth:`SessionLog.open`, naming what is missing)."""
    path = Path(path)
    return any((path / name).is_file() for name in ("calibration.json", "colour.txt", "colour_poses.txt", "depth_poses.txt"))


def _check_origin(origin) -> np.ndarray:
    o = np.asarray(origin, np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InvalidInputError(f"origin: expected three finite numbers, got {origin}")
    return o


# --------------------------------------------------------------------------------------------------
# RGB-D sequences (TUM RGB-D, ICL-NUIM): intrinsics, depth scale and poses
# --------------------------------------------------------------------------------------------------


def _presets() -> dict:
    from rgbd_envmap.icl import ICL_NUIM_INTRINSICS
    from rgbd_envmap.tum import TUM_INTRINSICS

    return {**TUM_INTRINSICS, "icl-nuim": ICL_NUIM_INTRINSICS}


#: the names ``--intrinsics`` takes besides a JSON file.
INTRINSICS_PRESETS = ("fr1", "fr2", "fr3", "default", "icl-nuim")


def _given_intrinsics(value: str):
    """(Intrinsics, (source, reason)) for ``--intrinsics VALUE``: a preset name or a JSON file."""
    from rgbd_envmap.types import Intrinsics

    presets = _presets()
    if value in presets:
        return presets[value], (value, f"--intrinsics {value}")
    path = Path(value)
    if not path.is_file():
        raise InvalidInputError(f"--intrinsics: expected one of {', '.join(INTRINSICS_PRESETS)} or a JSON file of "
                                f"Intrinsics (width, height, fx, fy, cx, cy, distortion), got {value!r} (no such file)")
    try:
        d = json.loads(path.read_text())
        if not isinstance(d, dict):
            raise TypeError(f"expected a JSON object, got {type(d).__name__}")
        intr = Intrinsics.from_dict(d)
    except json.JSONDecodeError as exc:
        raise LogFormatError(f"{path}, line {exc.lineno}: invalid JSON ({exc.msg})") from None
    except (ValueError, KeyError, TypeError, AttributeError, RgbdEnvmapError) as exc:
        raise LogFormatError(f"{path}: invalid intrinsics ({type(exc).__name__}: {exc}); expected the keys width, height, "
                             f"fx, fy, cx, cy and optionally distortion {{k1, k2, p1, p2, k3}}") from None
    return intr, (str(path), "--intrinsics FILE")


def _depth_correction(opts: ReplayOptions, seq) -> tuple[float, str | None]:
    """The factor on the metric depth that ``--tum-depth-correction`` asks for, and the camera it is
    that of: the freiburg preset in use, else the one the folder's name names."""
    from rgbd_envmap.tum import TUM_DEPTH_CORRECTION, tum_camera_from_name

    want = opts.tum_depth_correction
    if want is None:
        return 1.0, None
    if want == "auto":
        camera = seq.intrinsics_source[0]
        want = camera if camera in ("fr1", "fr2", "fr3") else tum_camera_from_name(seq.root)
        if want is None:
            raise InvalidInputError(f"--tum-depth-correction: neither the intrinsics in use ({camera}) nor the folder name "
                                    f"{Path(seq.root).name!r} names a freiburg camera, so the factor is unknown; name the "
                                    "camera with --intrinsics fr1|fr2|fr3")
    if want not in ("fr1", "fr2", "fr3"):
        raise InvalidInputError(f"--tum-depth-correction: expected fr1, fr2 or fr3, got {want!r}")
    return TUM_DEPTH_CORRECTION[want], want


def _sequence_info(seq, layout: str) -> dict:
    name, reason = seq.intrinsics_source
    return {
        "layout": layout,
        "intrinsics": {"source": name, "reason": reason, **seq.intrinsics.to_dict()},
        "depth_scale_units_per_m": seq.depth_scale,
        "depth_correction": seq.depth_correction,
        "poses_file": str(seq.trajectory),
        "pose_association": {"max_dt_s": seq.max_dt_s, "method": seq.poses},
    }


def run_replay_tum(opts: ReplayOptions) -> dict:
    """Replay a TUM RGB-D sequence through the Kinect path."""
    from rgbd_envmap.tum import TUM_DEPTH_SCALE, read_tum_sequence

    root = Path(opts.log)
    if opts.poses is None and not (root / "groundtruth.txt").is_file():
        raise LogFormatError(f"{root / 'groundtruth.txt'}: missing file (the benchmark's validation and test sequences "
                             "ship without ground truth: give an estimated trajectory with --poses FILE)")
    given = None if opts.intrinsics is None else _given_intrinsics(opts.intrinsics)
    seq = read_tum_sequence(root, intrinsics="auto" if given is None else given[0],
                            depth_scale=TUM_DEPTH_SCALE if opts.depth_scale is None else opts.depth_scale,
                            trajectory=opts.poses)
    if given is not None:
        seq.intrinsics_source = (given[1][0], given[1][1] + (" (overrides calibration.json)"
                                                             if (root / "calibration.json").is_file() else ""))
    seq.depth_correction, camera = _depth_correction(opts, seq)
    info = _sequence_info(seq, "TUM RGB-D")
    if camera is not None:
        info["depth_correction_camera"] = camera
    return _replay_rgbd(opts, seq, "replay (TUM RGB-D, Kinect path)", info)


def run_replay_icl(opts: ReplayOptions) -> dict:
    """Replay an ICL-NUIM sequence (TUM-compatible layout) through the Kinect path."""
    from rgbd_envmap.icl import read_icl_nuim_sequence
    from rgbd_envmap.tum import TUM_DEPTH_SCALE

    if opts.tum_depth_correction is not None:
        raise InvalidInputError("--tum-depth-correction: applies to the TUM RGB-D Kinects only, not to ICL-NUIM's renders")
    given = None if opts.intrinsics is None else _given_intrinsics(opts.intrinsics)
    seq = read_icl_nuim_sequence(opts.log, intrinsics=None if given is None else given[0],
                                 depth_scale=TUM_DEPTH_SCALE if opts.depth_scale is None else opts.depth_scale,
                                 trajectory=opts.poses)
    if given is not None:
        seq.intrinsics_source = given[1]
    return _replay_rgbd(opts, seq, "replay (ICL-NUIM, Kinect path)", _sequence_info(seq, "ICL-NUIM"))


def _replay_rgbd(opts: ReplayOptions, seq, source: str, info: dict) -> dict:
    """Run the Kinect path on an opened :class:`rgbd_envmap.tum.TumSequence`."""
    if not len(seq):
        raise LogFormatError(f"{opts.log}: no frame has rgb, depth and a pose within the association window (skipped: {seq.skipped}; "
                             f"poses from {seq.trajectory})")
    skipped: Counter = Counter({f"association_{k}": v for k, v in seq.skipped.items() if v})
    skipped_files: list[str] = []

    def load(i: int):
        try:
            return seq.load(i)
        except LogFormatError as exc:
            if opts.strict:
                raise
            skipped["frame"] += 1
            skipped_files.append(str(exc))
            return None

    if opts.origin is not None:
        origin = _check_origin(opts.origin)
    else:  # 1 m along the first readable frame's optical axis (unreadable ones are counted in the run)
        T = None
        for i in range(len(seq)):
            try:
                T = seq.load(i).T_world_from_cam
                break
            except LogFormatError:
                if opts.strict:
                    raise
        if T is None:
            raise LogFormatError(f"{opts.log}: no frame of the sequence could be read")
        origin = T.translation + T.rotation[:, 2]
    gt_path = Path(opts.log) / "groundtruth" / "envmap.npz"

    def groundtruth_envmap():
        if not gt_path.is_file():
            return None
        with np.load(gt_path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    truth_dir = Path(opts.log) / "groundtruth" / "frames"

    def with_truth():
        for i in range(len(seq)):
            f = load(i)
            if f is None:
                continue
            path = truth_dir / f"{f.timestamp_ns}.npz"
            gt = {}
            if path.is_file():
                with np.load(path, allow_pickle=False) as z:
                    gt = {k: z[k] for k in z.files}
            yield f, gt

    with Pipeline(opts.config, seq.pipeline_calibration, origin, cache_dir=opts.cache_dir) as pipe:
        summary = run_pipeline(
            pipe, with_truth(), len(seq),
            RunOptions(opts.out, composite_every=opts.composite_every, video=opts.video, progress=opts.progress, rerun=opts.rerun),
            groundtruth_envmap=groundtruth_envmap,
            extra=lambda: {"source": source, "log": str(opts.log), **info, "skipped": dict(skipped),
                           "skipped_files": skipped_files[:50]},
        )
    return summary


# --------------------------------------------------------------------------------------------------
# Session logs
# --------------------------------------------------------------------------------------------------


def run_replay_session(opts: ReplayOptions) -> dict:
    """Replay a session log of this project packet by packet."""
    log = SessionLog.open(opts.log)
    for warning in log.warnings:  # on the terminal now, in run.json at the end
        print(f"rgbd-envmap: warning: {warning}", file=sys.stderr)
    origin = _check_origin(opts.origin) if opts.origin is not None else default_origin(log)
    skipped: Counter = Counter()
    skipped_files: list[str] = []

    def packets():
        for kind, i, ns in log.entries():
            try:
                packet = log.read_depth(i, strict=opts.strict) if kind == "depth" else log.read_colour(i)
            except LogFormatError as exc:
                if opts.strict:
                    raise
                skipped[kind] += 1
                skipped_files.append(str(exc))
                continue
            try:
                gt = log.groundtruth(kind, ns)
            except LogFormatError as exc:
                skipped[f"{kind}_groundtruth"] += 1
                skipped_files.append(str(exc))
                gt = {}
            yield packet, gt

    with Pipeline(opts.config, log.calibration, origin, cache_dir=opts.cache_dir) as pipe:
        summary = run_pipeline(
            pipe, packets(), len(log),
            RunOptions(opts.out, composite_every=opts.composite_every, video=opts.video, progress=opts.progress, rerun=opts.rerun),
            groundtruth_envmap=lambda: _groundtruth_envmap(log),
            extra=lambda: {"source": "replay", "log": str(opts.log), "skipped": dict(skipped), "skipped_files": skipped_files[:50],
                           "dropped_points": dict(log.dropped_points), "warnings": list(log.warnings)},
        )
    return summary


def _is_icl_nuim(path: Path) -> bool:
    from rgbd_envmap.icl import is_icl_nuim_sequence

    return is_icl_nuim_sequence(path)


#: The layouts ``replay`` reads, tried in this order (a TUM sequence written by ``simulate`` also holds a
#: calibration.json, so TUM RGB-D comes before the session log). Append a :class:`Layout` to read more.
LAYOUTS: list[Layout] = [
    Layout("TUM RGB-D", "rgb.txt + depth.txt (+ groundtruth.txt, rgb/, depth/)", is_tum_sequence, run_replay_tum,
           sequence_options=True),
    Layout("ICL-NUIM", "associations.txt + one *.gt.freiburg (+ rgb/, depth/)", _is_icl_nuim, run_replay_icl,
           sequence_options=True),
    Layout("phone (Stray Scanner)", "odometry.csv + camera_matrix.csv + rgb.mp4 (+ depth/, confidence/)",
           is_phone_capture, run_replay_phone),
    Layout("session log", "calibration.json + depth.txt, colour.txt and their _poses.txt (written by simulate)",
           is_session_log, run_replay_session),
]


def _found(root: Path, limit: int = 12) -> str:
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in root.iterdir())
    if not names:
        return "nothing (empty folder)"
    return ", ".join(names[:limit]) + (f", … ({len(names) - limit} more)" if len(names) > limit else "")


def detect_layout(path: str | Path) -> Layout:
    """The first entry of :data:`LAYOUTS` that recognises ``path``.

    Raises:
        LogFormatError: ``path`` is not a folder, or no layout recognises it (one line naming the
            layouts known and the files found).
    """
    root = Path(path)
    if not root.is_dir():
        raise LogFormatError(f"{root}: not a folder (replay reads a folder: "
                             + "; ".join(f"{lay.name}: {lay.files}" for lay in LAYOUTS) + ")")
    for layout in LAYOUTS:
        if layout.recognise(root):
            return layout
    raise LogFormatError(f"{root}: not a layout replay knows (" + "; ".join(f"{lay.name}: {lay.files}" for lay in LAYOUTS)
                         + f"); found {_found(root)}")


def run_replay(opts: ReplayOptions) -> dict:
    layout = detect_layout(opts.log)
    if not layout.sequence_options:
        given = [flag for flag, value in (("--intrinsics", opts.intrinsics), ("--depth-scale", opts.depth_scale),
                                          ("--poses", opts.poses), ("--tum-depth-correction", opts.tum_depth_correction))
                 if value is not None]
        if given:
            raise InvalidInputError(f"{', '.join(given)}: apply to RGB-D sequences (TUM RGB-D, ICL-NUIM), not to a {layout.name} "
                                    f"({opts.log})")
    return layout.replay(opts)
