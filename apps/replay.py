"""``rgbd-envmap replay``: run the pipeline on a recorded sequence, no simulator involved.

The recording is opened by the library (:func:`rgbd_envmap.sources.frames.open_source`): its layout is
recognised by its files, in the order of :data:`rgbd_envmap.sources.frames.SOURCE_LAYOUTS` (TUM RGB-D,
ICL-NUIM, phone captures in the Stray Scanner layout, Redwood, RealSense bags, this project's session
logs), and every layout yields the same items through the same
:class:`~rgbd_envmap.sources.frames.FrameSource` protocol that :func:`rgbd_envmap.replay` reads. This
module adds only what a run folder needs: the options of the command line mapped onto
:class:`~rgbd_envmap.sources.options.SourceOptions`, the EM origin, the progress bar and the reports
(:func:`apps.run.run_pipeline`), and ``run.json``'s account of the source (layout, intrinsics and
why, depth scale, poses file, skipped files).

A folder that matches no layout fails with one line listing the layouts and the files found; an
option that does not apply to the layout found (``--intrinsics`` for a session log) fails naming the
layouts it applies to; a recording without poses (a RealSense bag, a TUM validation sequence, a Redwood
folder without its trajectory) fails naming ``--poses FILE``.

The EM origin is ``--origin`` if given, else the origin of the recording's true map
(``groundtruth/envmap.npz``, written by ``simulate``), else 1 m in front of the first colour frame's
camera (for an RGB-D recording: of the first readable frame's camera).

Corrupt data never builds a map silently: a packet or frame file that cannot be read (truncated PNG,
broken PLY, NaN points) is skipped and counted under ``skipped`` in ``run.json`` and the report, with
the file named, unless ``strict`` is set, in which case the error (naming the file and line) ends the
run. Index-level problems (missing files, unsorted timestamps, NaN poses) fail when the recording is
opened.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from apps.run import RunOptions, run_pipeline
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.pipeline import Pipeline, PipelineConfig
from rgbd_envmap.sources.frames import (
    SessionLogSource,
    SourceLayout,
    check_options,
    detect_source_layout,
    layout_named,
)
from rgbd_envmap.sources.options import INTRINSICS_PRESETS, SourceOptions, resolve_intrinsics

__all__ = ["ReplayOptions", "INTRINSICS_PRESETS", "run_replay", "run_replay_tum", "run_replay_icl", "run_replay_session",
           "default_origin", "source_options"]


@dataclass(frozen=True)
class ReplayOptions:
    """What ``replay`` was asked. ``intrinsics``, ``depth_scale`` and ``poses`` apply to RGB-D
    recordings (TUM RGB-D, ICL-NUIM, Redwood, RealSense) only, ``tum_depth_correction`` to TUM RGB-D,
    ``phone_*`` to phone captures; None: the layout's own."""

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
    #: a preset name (:data:`INTRINSICS_PRESETS`) or the path of a JSON file (``Intrinsics.to_dict()``
    #: or Open3D's PinholeCameraIntrinsic).
    intrinsics: str | None = None
    depth_scale: float | None = None
    #: a trajectory file (TUM format or ``.log``) used instead of the recording's own poses.
    poses: Path | None = None
    #: None: off; ``"auto"``: the factor of the freiburg camera in use; ``"fr1"`` / ``"fr2"`` / ``"fr3"``.
    tum_depth_correction: str | None = None
    #: phone captures: depth packets per second taken (None: every depth image); video decode size.
    phone_depth_rate_hz: float | None = 5.0
    phone_colour_size: tuple[int, int] | None = None


def default_origin(log) -> np.ndarray:
    """The true map's origin if the session log has one, else 1 m along the first colour camera's
    optical axis (:meth:`SessionLogSource.default_origin`)."""
    return SessionLogSource(log).default_origin()


def _check_origin(origin) -> np.ndarray:
    o = np.asarray(origin, np.float64)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise InvalidInputError(f"origin: expected three finite numbers, got {origin}")
    return o


def source_options(opts: ReplayOptions, layout: SourceLayout) -> SourceOptions:
    """The library's :class:`SourceOptions` for ``opts`` on ``layout``; a flag that does not apply to
    the layout is refused, naming the flag and the layouts it applies to (InvalidInputError)."""
    options = SourceOptions(intrinsics=opts.intrinsics, depth_scale=opts.depth_scale, poses=opts.poses,
                            depth_correction=opts.tum_depth_correction, strict=opts.strict,
                            depth_rate_hz=opts.phone_depth_rate_hz, colour_size=opts.phone_colour_size)
    check_options(layout, options, opts.log)
    if opts.intrinsics is not None:  # resolved here so that run.json names the flag: "--intrinsics fr1"
        intr, source = resolve_intrinsics(opts.intrinsics, "--intrinsics")
        options = replace(options, intrinsics=intr, intrinsics_source=source)
    return options


def run_replay(opts: ReplayOptions, *, layout: SourceLayout | None = None) -> dict:
    """Replay the recording ``opts.log`` (its layout detected, or ``layout``) into the run folder
    ``opts.out``; returns the run summary (also ``run.json``)."""
    lay = detect_source_layout(opts.log) if layout is None else layout
    src = lay.open(Path(opts.log), source_options(opts, lay))
    for warning in getattr(src, "warnings", ()):  # on the terminal now, in run.json at the end
        print(f"rgbd-envmap: warning: {warning}", file=sys.stderr)
    origin = _check_origin(opts.origin) if opts.origin is not None else src.default_origin()
    label = "replay" + (f" ({src.description})" if src.description else "")

    def extra() -> dict:
        return {"source": label, "log": str(opts.log), **src.info(), "skipped": dict(src.skipped),
                "skipped_files": src.skipped_files[:50]}

    with Pipeline(opts.config, src.calibration, origin, cache_dir=opts.cache_dir) as pipe:
        return run_pipeline(
            pipe, src.with_truth(), len(src),
            RunOptions(opts.out, composite_every=opts.composite_every, video=opts.video, progress=opts.progress, rerun=opts.rerun),
            groundtruth_envmap=src.truth, extra=extra,
        )


def run_replay_tum(opts: ReplayOptions) -> dict:
    """Replay a TUM RGB-D sequence through the Kinect path (what ``simulate --device kinect`` runs)."""
    return run_replay(opts, layout=layout_named("TUM RGB-D"))


def run_replay_icl(opts: ReplayOptions) -> dict:
    """Replay an ICL-NUIM sequence (TUM-compatible layout) through the Kinect path."""
    return run_replay(opts, layout=layout_named("ICL-NUIM"))


def run_replay_session(opts: ReplayOptions) -> dict:
    """Replay a session log of this project packet by packet."""
    return run_replay(opts, layout=layout_named("session log"))

