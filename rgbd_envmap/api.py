"""One call from a recording to a map: :func:`replay` → :class:`RunResult`.

``rgbd_envmap.replay(path)`` runs the pipeline over any recording ``rgbd-envmap replay`` reads (layout
detected by :func:`rgbd_envmap.sources.frames.open_source`) and returns the map in memory; it writes
nothing and never imports the apps. The CLI opens the recording with the same function and feeds
the same items in the same order, so with the same config and origin the map is bit for bit the one
its ``replay`` writes to ``envmap.npz``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from itertools import islice
from pathlib import Path

import numpy as np

from rgbd_envmap import metrics
from rgbd_envmap.checks import check_array
from rgbd_envmap.envmap.map import EnvironmentMap
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.pipeline import COLOUR_TOTAL, DEPTH_TOTAL, RENDER_STAGES, Pipeline, PipelineConfig
from rgbd_envmap.sources.frames import FrameSource, as_source, feed
from rgbd_envmap.timing import frame_totals, stage_stats, summarise

__all__ = ["RunResult", "replay", "default_replay_config"]


@dataclass(frozen=True)
class RunResult:
    """What :func:`replay` returns.

    Attributes:
        envmap: the final :class:`~rgbd_envmap.envmap.EnvironmentMap` (the pipeline's own, not a copy).
        coefficients: (n², 3) SH coefficients of the lighting at the end, n the bands in use.
        steps: depth steps run (Tango depth packets paired with colour; every ``kinect_em_every``-th
            RGB-D frame).
        timing: ``{stage: {"count", "median_ms", "p95_ms"}}`` per stage, plus ``depth_frame_total``
            and ``colour_frame_total`` (per frame sums, as in the CLI's ``timing.csv``).
        accuracy: against the source's true map, when it has one at the same origin **and the same
            resolution** as the map: ``em_coverage`` (:func:`rgbd_envmap.metrics.coverage_of`) and,
            where both cover pixels, ``em_ws_psnr_db`` (WS-PSNR of the radiance clipped to [0, 1] over
            those pixels). Empty otherwise (no truth, another origin, or another size: the CLI's
            ``accuracy.json`` downsamples a larger truth, this does not).
        skipped: counts of what the source passed over (unreadable packets or frames, frames the
            association dropped); empty when nothing was.
        origin: (3,) the EM origin used.
        packets: items fed to the pipeline (packets, or RGB-D frames).
    """

    envmap: EnvironmentMap
    coefficients: np.ndarray
    steps: int
    timing: dict
    accuracy: dict
    skipped: dict
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    packets: int = 0


def default_replay_config() -> PipelineConfig:
    """``PipelineConfig()`` with rendering off: :func:`replay` returns no composited frames, so
    rasterising the object would be time spent on nothing (the map does not depend on it)."""
    base = PipelineConfig()
    return replace(base, render=replace(base.render, enabled=False))


def _timing(records) -> dict:
    out = summarise(records)
    out[DEPTH_TOTAL] = stage_stats(frame_totals(records, "depth", exclude=RENDER_STAGES))
    out[COLOUR_TOTAL] = stage_stats(frame_totals(records, "colour"))
    return out


def _accuracy(em: EnvironmentMap, truth: Mapping | None) -> dict:
    if truth is None or not {"origin", "valid", "radiance"} <= set(truth):
        return {}
    gv = np.asarray(truth["valid"], bool)
    if gv.shape != em.valid.shape or not np.allclose(np.asarray(truth["origin"], np.float64), em.origin):
        return {}
    out: dict[str, float] = {}
    if gv.any():
        out["em_coverage"] = metrics.coverage_of(em.valid, gv)
    covered = em.valid & gv
    if covered.any():
        grad = np.asarray(truth["radiance"], np.float32)
        out["em_ws_psnr_db"] = metrics.ws_psnr(np.clip(em.radiance, 0, 1), np.clip(grad, 0, 1), covered)
    return out


def replay(source: str | Path | FrameSource, config: PipelineConfig | None = None, origin=None, *,
           poses: str | Path | None = None, max_packets: int | None = None,
           cache_dir: str | Path | None = None) -> RunResult:
    """Run the pipeline over a recording and return the map, coefficients, timing and accuracy.

    Args:
        source: a recording (a session log written by ``simulate``, a TUM RGB-D, ICL-NUIM or Redwood
            folder, a phone capture in the Stray Scanner layout, a RealSense ``.bag``: detected by its
            files, :data:`~rgbd_envmap.sources.frames.SOURCE_LAYOUTS`), or an open reader
            (:class:`~rgbd_envmap.logs.SessionLog`, :class:`~rgbd_envmap.tum.TumSequence`,
            :class:`~rgbd_envmap.sources.stray.StrayCapture`,
            :class:`~rgbd_envmap.sources.realsense.RealSenseBag`) or
            :class:`~rgbd_envmap.sources.frames.FrameSource`. Other opening settings:
            :func:`~rgbd_envmap.sources.frames.open_source` with a
            :class:`~rgbd_envmap.sources.options.SourceOptions`, then pass what it returns.
        config: the pipeline settings; None: :func:`default_replay_config` (``PipelineConfig()`` with
            rendering off: nothing is composited or written). Rendering on costs time and changes
            nothing returned.
        origin: (3,) world metres; None: the source's default (its true map's origin if it has one,
            else 1 m in front of the first colour camera; an RGB-D sequence: the first readable frame's).
        poses: a trajectory file (TUM format or ``.log``) for a recording path: instead of its own
            poses, or for one that has none (a RealSense bag, a Redwood folder without its trajectory).
        max_packets: feed at most this many items (packets, or RGB-D frames); None: all.
        cache_dir: where the object's PRT transfer is cached (None: the default cache).

    Raises:
        LogFormatError: a folder of no known layout (naming the layouts and the files found), a
            recording without poses (naming ``poses``), or a recording whose index cannot be read.
        InvalidInputError: a bad origin, ``max_packets`` or source object.
    """
    if max_packets is not None and (isinstance(max_packets, bool) or not isinstance(max_packets, (int, np.integer))
                                    or max_packets < 0):
        raise InvalidInputError(f"max_packets: expected an integer ≥ 0 or None, got {max_packets!r}")
    if config is None:
        config = default_replay_config()
    elif not isinstance(config, PipelineConfig):
        raise InvalidInputError(f"config: expected a PipelineConfig, got {type(config).__name__}")
    src = as_source(source) if poses is None else as_source(source, poses=poses)
    o = src.default_origin() if origin is None else check_array(origin, "origin", shape=(3,), finite=True)
    o = np.asarray(o, np.float64)
    items = iter(src) if max_packets is None else islice(iter(src), int(max_packets))
    n = 0
    with Pipeline(config, src.calibration, o, cache_dir=cache_dir) as pipe:
        if src.kind not in ("rgbd", "tango"):
            raise InvalidInputError(f"source.kind: expected 'tango' or 'rgbd', got {src.kind!r}")
        for item in items:
            n += 1
            feed(pipe, item)
        pipe.finish()
        em = pipe.capture.em
        coeffs = np.array(pipe.coeffs[: pipe.bands * pipe.bands], copy=True)
        return RunResult(envmap=em, coefficients=coeffs, steps=int(pipe.depth_steps), timing=_timing(pipe.timer.records),
                         accuracy=_accuracy(em, src.truth()), skipped={k: v for k, v in src.skipped.items() if v},
                         origin=o.copy(), packets=n)
