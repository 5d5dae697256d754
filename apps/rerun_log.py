"""Optional ``--rerun FILE.rrd`` recording of a run for the rerun viewer (rerun-sdk, offline file).

Logged on the ``session`` timeline (seconds from the first packet): the colour camera's pose and
pinhole under ``world/colour_camera`` with the composited frame (JPEG) as its image; per depth frame,
the map (tone-mapped colour and depth, downsampled to 500×250) under ``envmap/``, the EM origin and the
object's base under ``world/``, and scalars (pairs, MSE, pixels taken) under ``metrics/``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from apps.preview import depth_to_colourmap, tonemap
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.pipeline import ColourStep, DepthStep, Pipeline

__all__ = ["RerunRecorder"]

_EM_PREVIEW = (500, 250)


class RerunRecorder:
    def __init__(self, path: Path, pipeline: Pipeline) -> None:
        try:
            import rerun as rr
        except ImportError:
            raise InvalidInputError("--rerun needs rerun-sdk: pip install rerun-sdk==0.41.0") from None
        self.rr = rr
        self.pipeline = pipeline
        self.rec = rr.RecordingStream("rgbd-envmap")
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.rec.save(str(path))
        self._t0: int | None = None
        intr = pipeline.calibration.colour
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log("world/colour_camera/image", rr.Pinhole(
            focal_length=[intr.fx, intr.fy], principal_point=[intr.cx, intr.cy], resolution=[intr.width, intr.height],
            camera_xyz=rr.ViewCoordinates.RDF), static=True)

    def _time(self, timestamp_ns: int) -> None:
        if self._t0 is None:
            self._t0 = timestamp_ns
        self.rec.set_time("session", duration=(timestamp_ns - self._t0) * 1e-9)

    def colour(self, step: ColourStep, T_world_from_colour) -> None:
        rr = self.rr
        self._time(step.timestamp_ns)
        T = T_world_from_colour
        self.rec.log("world/colour_camera", rr.Transform3D(translation=T.translation, mat3x3=T.rotation))
        image = step.image if step.image is not None else step.frame_srgb
        self.rec.log("world/colour_camera/image", rr.Image(image).compress(jpeg_quality=85))

    def depth(self, step: DepthStep) -> None:
        rr = self.rr
        self._time(step.timestamp_ns)
        em = self.pipeline.capture.em
        cap = step.capture
        self.rec.log("metrics/pairs", rr.Scalars(float(cap.n_pairs)))
        if cap.ccm is not None and np.isfinite(cap.ccm.mse):
            self.rec.log("metrics/ccm_mse", rr.Scalars(float(cap.ccm.mse)))
        if cap.update is not None:
            self.rec.log("metrics/em_pixels_taken", rr.Scalars(float(cap.update.taken)))
        self.rec.log("world/em_origin", rr.Points3D([em.origin], radii=0.02, colors=[[255, 200, 0]]))
        self.rec.log("world/object_base", rr.Points3D([self.pipeline.object_base], radii=0.015, colors=[[0, 200, 255]]))
        if step.capture.projected and em.valid.any():
            small = cv2.resize(np.ascontiguousarray(em.radiance), _EM_PREVIEW, interpolation=cv2.INTER_AREA)
            valid = cv2.resize(em.valid.astype(np.uint8), _EM_PREVIEW, interpolation=cv2.INTER_NEAREST).astype(bool)
            depth = cv2.resize(em.depth_m, _EM_PREVIEW, interpolation=cv2.INTER_NEAREST)
            self.rec.log("envmap/colour", rr.Image(tonemap(small, valid)))
            self.rec.log("envmap/depth", rr.Image(depth_to_colourmap(depth, valid, 4.0)))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()
