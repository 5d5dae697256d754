"""The capture-and-relight pipeline of paper 003, run per sensor packet, with per-stage timing.

- :mod:`~rgbd_envmap.pipeline.config`: :class:`PipelineConfig`, the whole configuration tree;
- :mod:`~rgbd_envmap.pipeline.capture`: :class:`EnvironmentCapture`, colour correction against the
  map, then the map update;
- :mod:`~rgbd_envmap.pipeline.facade`: :class:`Pipeline`, which feeds Tango packets or Kinect RGB-D
  frames through ingest, capture, SH lighting, shading and compositing, timing every stage.
"""

from rgbd_envmap.pipeline.capture import FILLED_PIXEL_MODES, CaptureConfig, CaptureStep, EnvironmentCapture
from rgbd_envmap.pipeline.config import ObjectConfig, PipelineConfig, PoseCheckConfig, RenderConfig, ShadingConfig
from rgbd_envmap.pipeline.facade import (
    COLOUR_TOTAL,
    DEPTH_TOTAL,
    PAPER_TABLE1_MS,
    RENDER_STAGES,
    STAGES,
    ColourStep,
    DepthStep,
    Pipeline,
)

__all__ = [
    "Pipeline", "PipelineConfig", "ShadingConfig", "ObjectConfig", "RenderConfig", "PoseCheckConfig", "DepthStep", "ColourStep",
    "EnvironmentCapture", "CaptureConfig", "CaptureStep", "FILLED_PIXEL_MODES",
    "STAGES", "RENDER_STAGES", "DEPTH_TOTAL", "COLOUR_TOTAL", "PAPER_TABLE1_MS",
]
