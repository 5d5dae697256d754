"""HDR capture: frames brought to one exposure, and their clipped pixels flagged.

A camera clips at its full scale, so a lamp brighter than the exposure allows enters an 8-bit frame
at the clip level. Phones report each frame's exposure time and ISO; their product is the sensor's
linear gain up to a constant, so a frame's decoded linear colours divided by it (here: multiplied by
``reference exposure / frame exposure``, which keeps the map in the reference frame's colour space)
agree across exposures wherever no channel clipped. :func:`hdr_frame` does that to an RGB-D frame
and flags the pixels with a channel above the clip level, measured in the sensor's linear space
before any colour-correction mixing; the map update keeps such a colour only as a lower bound
(:func:`rgbd_envmap.envmap.update`, ``clipped``). With exposure bracketing (a few frames at −4 and
−2 EV among the live ones) the lamp is seen unclipped and the map keeps its true radiance.
docs/design/hdr.md gives the rules and the measurements.

References:
    Nikodým, Havran et al., Multiple Live Video Environment Map Sampling, §3 (three exposures fused
    into one HDR light probe per frame).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rgbd_envmap._kernels.hdr_flags import low_confidence_kernel
from rgbd_envmap.checks import check_array, check_flag, check_instance, check_number
from rgbd_envmap.types import RGBDFrame

__all__ = ["HDRConfig", "clipped_pixels", "low_confidence_pixels", "exposure_scale", "hdr_frame"]


@dataclass(frozen=True)
class HDRConfig:
    """HDR capture in the pipeline (ours; docs/design/hdr.md)."""

    #: bring each frame to the reference frame's exposure (from the packets' exposure time × ISO)
    #: and flag its clipped pixels for the map update. False: frames as decoded, no clip flags (the
    #: paper: an LDR map), and bracketed frames composited like live ones.
    enabled: bool = True
    #: a channel whose decoded linear value (before colour correction) exceeds this is clipped; the
    #: paper's exposure rule calls the same pixels too bright to pair (0.95).
    clip_level: float = 0.95
    #: a bracketed frame's pixels darker than this in every channel (decoded linear) neither pair
    #: for its colour fit (the exposure rule's dark threshold, 0.05 for live frames) nor overwrite
    #: the live frames' colours in the map (they are flagged as clipped pixels are): at −4 EV a
    #: grey wall sits near code 25, where quantisation and read noise dominate (0.01 and 0.005 measured
    #: alike on the default session, 0.02 lost the −4 EV frame that sees the lamp: docs/design/hdr.md).
    bracket_dark: float = 0.01

    def __post_init__(self) -> None:
        check_flag(self.enabled, "HDRConfig.enabled")
        check_number(self.clip_level, "HDRConfig.clip_level", low=0.0, high=1.0, low_open=True)
        check_number(self.bracket_dark, "HDRConfig.bracket_dark", low=0.0, high=self.clip_level)


def clipped_pixels(rgb: np.ndarray, clip_level: float = 0.95) -> np.ndarray:
    """(H, W) bool: pixels of (H, W, 3) decoded linear RGB with any channel above ``clip_level``
    (NaN is not clipped)."""
    return low_confidence_pixels(rgb, clip_level)


def low_confidence_pixels(rgb: np.ndarray, clip_level: float = 0.95, dark: float | None = None) -> np.ndarray:
    """(H, W) bool: the pixels HDR capture flags in (H, W, 3) decoded linear RGB: any channel above
    ``clip_level`` (clipped) or, with ``dark`` given (a bracket frame), no channel at ``dark`` or
    above (too dark to measure; the live frames see it better). NaN neither clips nor reaches
    ``dark``. The levels are compared in the array's precision (float32 for the decoded frames)."""
    rgb = check_array(rgb, "rgb", shape=("H", "W", 3), dtype="float")
    level = check_number(clip_level, "clip_level", low=0.0, high=1.0, low_open=True)
    use_dark = dark is not None
    dark_v = check_number(dark, "dark", low=0.0, high=level) if use_dark else 0.0
    out = np.empty(rgb.shape[:2], bool)
    t = rgb.dtype.type
    low_confidence_kernel(rgb, t(level), t(dark_v), use_dark, out)
    return out


def exposure_scale(reference_exposure: float | None, exposure: float | None) -> float:
    """The factor that brings a frame of ``exposure`` to ``reference_exposure`` (both exposure time ×
    ISO): their ratio, or 1 where either is unknown (the frame is taken as it is)."""
    if reference_exposure is None or exposure is None:
        return 1.0
    ref = check_number(reference_exposure, "reference_exposure", low=0.0, low_open=True)
    e = check_number(exposure, "exposure", low=0.0, low_open=True)
    return float(ref / e)


def hdr_frame(frame: RGBDFrame, scale: float, clipped: np.ndarray) -> RGBDFrame:
    """``frame`` with its colours multiplied by ``scale`` (float32) and ``clipped`` ((H, W) bool,
    from :func:`clipped_pixels` of the decoded colours) as its clip flags."""
    check_instance(frame, RGBDFrame, "frame")
    s = check_number(scale, "scale", low=0.0, low_open=True)
    clipped = check_array(clipped, "clipped", shape=frame.known.shape, dtype="bool")
    rgb = frame.rgb if s == 1.0 else frame.rgb * np.float32(s)
    return replace(frame, rgb=rgb, clipped=clipped)
