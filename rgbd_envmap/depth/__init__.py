"""Depth-image stages of the RGB-D frame: reliability marking (paper 003 §5.2) and hole filling
(§4.2, eq. 1), each with named baselines behind one method dispatcher, and edge-aware denoising.

``mark_reliable`` lives in :mod:`rgbd_envmap.depth.reliability`, ``fill_holes`` in
:mod:`rgbd_envmap.depth.holes`; both are re-exported here, as ``depth.mark_reliable`` and
``depth.fill_holes`` (docs/design/overview.md). The denoiser is :mod:`rgbd_envmap.depth.denoise`.
"""

from rgbd_envmap.depth.holes import FILL_METHODS, fill_holes, fill_holes_flagged
from rgbd_envmap.depth.reliability import RELIABILITY_METHODS, mark_reliable

__all__ = ["fill_holes", "fill_holes_flagged", "mark_reliable", "FILL_METHODS", "RELIABILITY_METHODS"]
