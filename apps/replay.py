"""``rgbd-envmap replay``: run the pipeline on a recorded session log, no simulator involved.

A public TUM RGB-D layout (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``rgb/``, ``depth/``) is
recognised and replayed through the Kinect path (warp + merge) with no conversion step
(:func:`rgbd_envmap.tum.read_tum_sequence`: intrinsics from ``calibration.json`` if present, else the
TUM defaults; rgb, depth and poses associated by nearest timestamp; images without a pose skipped and
counted). Any other folder is a session log of this project.

A session log is read packet by packet (:class:`rgbd_envmap.logs.SessionLog`); ground truth stored beside it
(``groundtruth/``) feeds the accuracy report when present. The EM origin is ``--origin`` if given,
else the origin of the log's true map (``groundtruth/envmap.npz``, written by ``simulate``), else 1 m
in front of the first colour frame's camera.

Corrupt data never builds a map silently: a packet file that cannot be read (truncated PNG, broken
PLY, NaN points) is skipped and counted under ``skipped`` in ``run.json`` and the report, with the
file named, unless ``strict`` is set, in which case the error (naming the file and line) ends the run.
Index-level problems (missing files, unsorted timestamps, NaN poses) fail when the log is opened.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from apps.run import RunOptions, run_pipeline
from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.logs import SessionLog
from rgbd_envmap.pipeline import Pipeline, PipelineConfig

__all__ = ["ReplayOptions", "run_replay", "run_replay_tum", "default_origin", "is_tum_sequence"]


@dataclass(frozen=True)
class ReplayOptions:
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


def _groundtruth_envmap(log: SessionLog) -> dict | None:
    path = log.root / "groundtruth" / "envmap.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError) as exc:
        raise LogFormatError(f"{path}: unreadable NPZ ({exc})") from None


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


def _check_origin(origin) -> np.ndarray:
    o = np.asarray(origin, np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InvalidInputError(f"origin: expected three finite numbers, got {origin}")
    return o


def run_replay_tum(opts: ReplayOptions) -> dict:
    """Replay a TUM RGB-D sequence through the Kinect path."""
    from rgbd_envmap.tum import read_tum_sequence

    seq = read_tum_sequence(opts.log)
    if not len(seq):
        raise LogFormatError(f"{opts.log}: no frame has rgb, depth and a pose within the association window (skipped: {seq.skipped})")
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

    with Pipeline(opts.config, seq.calibration, origin, cache_dir=opts.cache_dir) as pipe:
        summary = run_pipeline(
            pipe, with_truth(), len(seq),
            RunOptions(opts.out, composite_every=opts.composite_every, video=opts.video, progress=opts.progress, rerun=opts.rerun),
            groundtruth_envmap=groundtruth_envmap,
            extra=lambda: {"source": "replay (TUM RGB-D, Kinect path)", "log": str(opts.log), "skipped": dict(skipped),
                           "skipped_files": skipped_files[:50]},
        )
    return summary


def run_replay(opts: ReplayOptions) -> dict:
    if is_tum_sequence(opts.log):
        return run_replay_tum(opts)
    log = SessionLog.open(opts.log)
    origin = _check_origin(opts.origin) if opts.origin is not None else default_origin(log)
    skipped: Counter = Counter()
    skipped_files: list[str] = []

    def packets():
        for kind, i, ns in log.entries():
            try:
                packet = log.read_depth(i) if kind == "depth" else log.read_colour(i)
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
            extra=lambda: {"source": "replay", "log": str(opts.log), "skipped": dict(skipped), "skipped_files": skipped_files[:50]},
        )
    return summary
