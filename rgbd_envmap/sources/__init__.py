"""Readers (and writers) of capture formats recorded by other devices, turned into the pipeline's own
packets (:class:`~rgbd_envmap.types.DepthPacket`, :class:`~rgbd_envmap.types.ColourPacket`) and a
:class:`~rgbd_envmap.types.Calibration`, so that :class:`rgbd_envmap.pipeline.Pipeline` runs them
unchanged.

- :mod:`rgbd_envmap.sources.stray`: iPhone / iPad LiDAR captures in the Stray Scanner layout
  (``rgb.mp4``, ``depth/``, ``confidence/``, ``camera_matrix.csv``, ``odometry.csv``), through the
  mobile (Tango) path.
"""

from rgbd_envmap.sources.stray import (
    CONFIDENCE_VALUES,
    T_WORLD_FROM_ARKIT,
    StrayCapture,
    StrayFrame,
    StrayWriter,
    depth_packet_from_image,
    is_stray_capture,
    pose_from_arkit,
    pose_to_arkit,
    read_stray_capture,
)

__all__ = [
    "CONFIDENCE_VALUES",
    "T_WORLD_FROM_ARKIT",
    "StrayCapture",
    "StrayFrame",
    "StrayWriter",
    "depth_packet_from_image",
    "is_stray_capture",
    "pose_from_arkit",
    "pose_to_arkit",
    "read_stray_capture",
]
