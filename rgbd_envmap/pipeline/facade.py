"""The capture-and-relight pipeline of paper 003, run per sensor packet, with per-stage timing.

:class:`Pipeline` consumes the device's packets in delivery order, as the paper's implementation
does (§7.2, §8):

- A **depth packet** (5 Hz) runs the whole chain once its colour frame is there (the colour frame
  with the nearest timestamp within ``max_colour_lag_ms``; the Tango delivers both together):
  NV21 → linear RGB, point cloud → RGB-D frame, depth denoising (ours; ``ingest.denoise_half_window``),
  reliability marking, hole filling, paired samples, colour-correction matrix (with its gate), EM
  update (the paper's rules plus free-space carving, ours), SH projection, and the object's shading
  (PRT transfer × SH coefficients) and shadow-plane alphas.
- Every **colour frame** (30 Hz) is composited: the object, shaded in the reference colour space with
  the latest SH coefficients, is mapped into the frame's colour space by the inverse of the latest
  accepted correction matrix, rasterised with a virtual camera matching the colour camera, and drawn
  over the frame with its soft shadow.

Stages are timed under the names of the paper's Table 1 (:data:`STAGES`); ``depth_frame_total`` is all
stages of a depth packet except rendering, ``colour_frame_total`` is shade + rasterise + composite of
a colour frame. The EM is the only state besides the latest matrix, coefficients and shading.

**Lighting from a file.** With ``lighting`` (or ``shading.lighting_file``) the object is lit by that
fixed map instead of the captured one: its SH coefficients are projected once, when the pipeline is
built, and the object is shaded from them; depth packets still correct and update the captured map
(stages "Calculate SH coefficients*" and "Shade object (PRT)" then do not run per packet). A real HDR
map is the usual baseline for captured lighting.

**A faulty device.** Packets the pipeline cannot use are skipped and counted in :attr:`Pipeline.skipped`
under a reason of :data:`SKIP_REASONS`: a packet not after the previous one of its stream (delivered
late), packets missing from a stream (counted from the stream's rate), an empty point cloud, a
depth packet after a pose jump or with a frozen pose (:class:`~rgbd_envmap.pipeline.config.PoseCheckConfig`),
a colour frame that repeats the previous image (shown as it is, without the object, and not paired)
and a depth packet with no colour frame within ``max_colour_lag_ms``. None of these checks fires on a
well-behaved device, whose results they leave unchanged.

The object stands on the surface under the EM origin: its base is ``object.base_below_origin_m``
below the origin (the EM origin is the paper's "virtual object position"). :meth:`Pipeline.move_object`
displaces it; the lighting then comes from the EM translated to the new position (§6.2), either as
a temporary view (recomputed after each update) or permanently (the map itself moves).

References:
    Monroy, Hudon, Smolic (2018), §4–§8, Table 1.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rgbd_envmap import sh
from rgbd_envmap.checks import check_array, check_instance
from rgbd_envmap.colour import decode_nv21, exposure_scale, hdr_frame, low_confidence_pixels
from rgbd_envmap.envmap.map import EnvironmentMap
from rgbd_envmap.envmap.translation import translate
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.ingest.kinect import KinectMerger, kinect_rgbd_frame
from rgbd_envmap.ingest.tango import colour_filled, registration_matrix, rgbd_frame_from_packets
from rgbd_envmap.pipeline.capture import CaptureStep, EnvironmentCapture
from rgbd_envmap.pipeline.config import PipelineConfig
from rgbd_envmap.pipeline.consistency import MapConsistency, extrapolated_pose, map_consistency
from rgbd_envmap.timing import StageTimer
from rgbd_envmap.types import Calibration, ColourPacket, DepthPacket, RGBDFrame, RigidTransform

__all__ = ["DepthStep", "ColourStep", "Pipeline", "STAGES", "DEPTH_TOTAL", "COLOUR_TOTAL", "PAPER_TABLE1_MS", "SKIP_REASONS"]

#: why a packet was skipped (the keys of :attr:`Pipeline.skipped`) and what that means.
SKIP_REASONS = {
    "depth_out_of_order": "a depth packet whose timestamp is not after the previous depth packet's (delivered late)",
    "colour_out_of_order": "a colour frame whose timestamp is not after the previous frame's (delivered late)",
    "depth_missing": "depth packets that never arrived (a gap in the stream, counted from its rate)",
    "colour_missing": "colour frames that never arrived (a gap in the stream, counted from its rate)",
    "depth_no_points": "an empty point cloud",
    "depth_pose_jump": "a depth packet within pose_check.jump_hold_s of a jump of the reported pose (faster than a hand moves)",
    "depth_pose_frozen": "a depth pose bit for bit equal to the previous depth packet's (a frozen tracker)",
    "colour_frozen_frame": "a colour frame repeating the previous image: shown without the object, not paired",
    "depth_no_colour": "a depth packet with no colour frame within max_colour_lag_ms (nor colour_fallback_lag_ms)",
    "depth_inconsistent_with_map": "a depth packet after a pose jump whose reported pose does not fit the map "
                                   "better than the pose with the jump undone (pose_check.map_check: a relocalisation error)",
}

#: stage names, in pipeline order, and the paper's Table 1 figure for each (None: no counterpart).
STAGES = (
    "Warp + merge depth (Kinect)", "Depth image to RGB-D",
    "YUV420 to linear RGB", "Point cloud to RGB-D", "Denoise depth", "Mark reliable RGB-D", "HDR exposure + clip flags",
    "Hole filling RGB-D", "Collect paired samples", "Compute colour correction matrix", "Calculate MSE", "Project sample to EM*",
    "EM translation", "Calculate SH coefficients*", "Select SH bands", "Lights from the map", "Receiver geometry",
    "Shade object (PRT)", "Shade receivers", "Decode colour frame", "Rasterise", "Composite",
)
DEPTH_TOTAL = "depth_frame_total"
COLOUR_TOTAL = "colour_frame_total"
#: two packets' poses (in the colour camera's frame) closer than this (metres, and rotation entries) are
#: the same frozen pose: a tracker that stopped reports one pose for both streams, a moving device's
#: tracking noise is millimetres.
FROZEN_POSE_TOL = 1e-7
#: stages that are not part of a depth frame's total (they belong to rendering a colour frame).
RENDER_STAGES = ("Decode colour frame", "Rasterise", "Composite")
#: a colour frame's total: everything it does to be shown (decode, shade when due, rasterise, composite).
PAPER_TABLE1_MS = {
    "Transfer data to GPU": 10.02, "YUV420 to linear RGB": 1.00, "Point cloud to RGB-D": 2.69,
    "Mark reliable RGB-D": 0.06, "Hole filling RGB-D": 0.08, "Collect paired samples": 2.35,
    "Compute colour correction matrix": 13.97, "Calculate MSE": 2.69, "Project sample to EM*": 0.21,
    "Calculate SH coefficients*": 0.46, "EM translation": 28.02, "Render frame": 20.7, "Total": 54.22,
}


@dataclass(frozen=True)
class DepthStep:
    """What one depth packet did.

    Attributes:
        timestamp_ns: the depth packet's.
        colour_timestamp_ns: the colour frame it was paired with.
        capture: colour correction + EM update outcome (:class:`~rgbd_envmap.pipeline.capture.CaptureStep`).
        raw_depth_m, filled_depth_m, filled_known, raw_known: the ingested frame before / after hole
            filling ((H, W) in the depth sensor's grid), for error measurement.
        sh_updated: the SH coefficients were recomputed.
        bands: SH bands in use after this packet.
        exposure_scale: the factor the frame's colours were multiplied by before correction (HDR
            capture: a bracketed frame brought to the exposure of the live frame whose correction
            matrix is in force; 1 otherwise).
    """

    timestamp_ns: int
    colour_timestamp_ns: int
    capture: CaptureStep
    raw_depth_m: np.ndarray
    raw_known: np.ndarray
    filled_depth_m: np.ndarray
    filled_known: np.ndarray
    sh_updated: bool
    bands: int
    exposure_scale: float = 1.0


@dataclass(frozen=True)
class ColourStep:
    """A composited colour frame: ``image`` (H, W, 3) uint8 sRGB, or None with rendering off."""

    timestamp_ns: int
    image: np.ndarray | None
    frame_srgb: np.ndarray


def _lighting_arrays(lighting) -> tuple[np.ndarray, np.ndarray | None]:
    """(radiance (H, W, 3), valid (H, W) or None) of a fixed lighting map (see :class:`Pipeline`)."""
    if hasattr(lighting, "radiance") and hasattr(lighting, "valid"):
        return lighting.radiance, lighting.valid
    if isinstance(lighting, tuple) and len(lighting) == 2:
        return lighting[0], lighting[1]
    if isinstance(lighting, np.ndarray):
        return lighting, None
    raise InvalidInputError("lighting: expected an EnvironmentMap, an object with radiance and valid, a (radiance, "
                            f"valid) pair or an (H, W, 3) radiance array, got {type(lighting).__name__}")


class _Done:
    """A finished job's result, with the interface of a future."""

    def __init__(self, value) -> None:
        self._value = value

    def result(self):
        return self._value


def _receiver_geometry(depth_m: np.ndarray, valid: np.ndarray, origin: np.ndarray, shader, base: np.ndarray, rc,
                       bands: int, *, own_occluder: bool):
    """(receiver mesh, its occlusion by the object) from the map's depth: the map's surfaces near
    the object merged with the support plane through its base where the map has none (2
    spacings away). ``own_occluder``: cast the occlusion rays against a copy of the shader's
    occluder (a rebuild beside the depth frames must not share the one their shadow rays use)."""
    from rgbd_envmap.render.differential import ObjectOccluder, receiver_occlusion
    from rgbd_envmap.render.geometry import merge_receivers, receiver_mesh, support_plane

    occluder = shader.occluder
    if own_occluder:
        occluder = ObjectOccluder(occluder.vertices, occluder.faces)
    mesh = receiver_mesh(depth_m, valid, origin, occluder.centre, rc.receiver_radius_m, spacing_m=rc.receiver_spacing_m)
    plane = support_plane(base, rc.receiver_radius_m, rc.receiver_spacing_m)
    mesh = merge_receivers(mesh, plane, 2 * rc.receiver_spacing_m)
    return mesh, receiver_occlusion(mesh, occluder, bands, samples=shader.samples)


class Pipeline:
    """Runs the stages per packet (see the module docstring); ``feed`` packets in delivery order."""

    def __init__(
        self,
        config: PipelineConfig,
        calibration: Calibration,
        origin: np.ndarray,
        *,
        cache_dir: str | Path | None = None,
        timer: StageTimer | None = None,
        lighting=None,
    ) -> None:
        """Args:
            config, calibration: the settings and the device's calibration.
            origin: (3,) world metres, the map's origin (the object's position).
            cache_dir: where the object's PRT transfer is cached.
            timer: collects the stage timings (a new one by default).
            lighting: a fixed lighting map instead of the captured one: an
                :class:`~rgbd_envmap.envmap.EnvironmentMap` or anything with ``radiance`` (H, W, 3) and
                ``valid`` (H, W) in our orientation (e.g. :class:`~rgbd_envmap.envmap_io.EnvmapFile`), a
                ``(radiance, valid)`` pair, or an (H, W, 3) radiance array (every pixel valid). None:
                the file ``config.shading.lighting_file`` if set, else the captured map.
        """
        self.config = config
        self.calibration = calibration
        self.capture = EnvironmentCapture(check_array(origin, "origin", shape=(3,), finite=True), config.capture,
                                          threads=config.threads)
        self.timer = timer or StageTimer()
        self._merger = KinectMerger(calibration.depth, config.kinect) if calibration.sensor == "kinect" else None
        self._kinect_frames = 0
        max_bands = max(config.shading.bands, config.shading.max_bands if config.shading.auto_bands else 1)
        self.sh_bands_computed = max_bands
        self.bands = config.shading.bands
        self.coeffs = np.zeros((max_bands * max_bands, 3))
        # Follows the map's updates: after the first frame only the written pixels are projected.
        self._projection = sh.IncrementalProjection(max_bands)
        self.has_lighting = False
        self.object_offset = np.zeros(3)
        self._translated: EnvironmentMap | None = None  # the last translated view, overwritten by the next
        self._pending_depth: DepthPacket | None = None
        # The usable colour frame nearest the pending depth packet among those that came before
        # it (a fallback partner when its own frame never comes: ``colour_fallback_lag_ms``).
        self._pending_partner: tuple[ColourPacket, np.ndarray] | None = None
        #: depth packets paired with a colour frame beyond ``max_colour_lag_ms`` (within
        #: ``colour_fallback_lag_ms``) because their own frame was lost or frozen.
        self.late_pairs = 0
        self._decode_ms = 0.0
        self._last_colour: tuple[ColourPacket, np.ndarray] | None = None
        #: bracketed colour frames (HDR capture): paired with depth for the map, not composited.
        self.bracketed_frames = 0
        # exposure time × ISO of the live frame whose correction matrix is in force (HDR capture)
        self._matrix_exposure: float | None = None
        self.depth_steps = 0
        self.dropped_depth = 0
        #: {reason: packets skipped} (reasons: :data:`SKIP_REASONS`; only those that occurred).
        self.skipped: dict[str, int] = {}
        self._stream: dict[str, list] = {}  # kind -> [first ns, last ns, last grid index]
        self._last_pose: tuple[int, np.ndarray] | None = None  # the previous packet's device (colour) pose
        self._last_depth_pose: np.ndarray | None = None
        self._jumped = False
        self._jump_ns: int | None = None  # the last jump's timestamp
        self._pose_before: tuple[int, np.ndarray] | None = None  # the packet pose before _last_pose (other time)
        # (4, 4) world-side transform that undoes the last jump (from the motion before it), while
        # the map check still tests it; None: no jump under test.
        self._correction: np.ndarray | None = None
        self._offset_confirmed = False  # the map check found the jump to be the tracker's error
        #: the map check of the last depth packet paired: (as reported, with the jump undone), or None.
        self.map_consistency: tuple[MapConsistency, MapConsistency] | None = None
        #: depth packets the map check found inconsistent but let in (``pose_check.map_accept_after_s``).
        self.map_check_accepted = 0
        #: pose jumps that ended a frozen pose (a tracker catching up), taken without a hold
        self.frozen_resumes = 0
        self._prev_nv21: np.ndarray | None = None
        self._colour_from_depth = calibration.T_colour_from_depth.inverse().matrix
        self._renderer = None
        self._object = None
        self._transfer = None
        self._plane = None
        self._cache_dir = cache_dir
        self.colours: np.ndarray | None = None  # (V, 3) shaded object, reference colour space
        self._shade_out: np.ndarray | None = None
        self._gram = None
        self.plane_alpha: np.ndarray | None = None
        # differential composite (render.composite = "differential"): lights, indirect SH, shader
        self.lights = None
        self.coeffs_indirect: np.ndarray | None = None
        self.receiver_ratio: np.ndarray | None = None
        self._diff_shader = None
        self._diff_base: np.ndarray | None = None
        self._receiver_faces = np.zeros((0, 3), np.int32)
        self._relights_since_geometry = 0
        # a receiver rebuild under way: (its future, the shader it is for, relights until it is used)
        self._geometry_job: tuple | None = None
        self._geometry_pool = None  # the second core's thread for receiver rebuilds (config.threads ≥ 2)
        self._light_state = None  # the sampler's state (Q2-Tree, Hemigon), relight to relight
        self._lights_sh: np.ndarray | None = None  # the direct part's SH when self.lights was sampled
        #: relights that kept the last lights (their direct part within render.lights_tolerance)
        self.lights_kept = 0
        if config.render.enabled or config.shading.auto_bands:
            self._load_object()
        if lighting is None and config.shading.lighting_file is not None:
            from rgbd_envmap.envmap_io import read_envmap

            lighting = read_envmap(config.shading.lighting_file, config.shading.lighting_convention)
        #: the object is lit by a fixed map given at construction, not by the captured one.
        self.fixed_lighting = lighting is not None
        if self.fixed_lighting:
            # Projected once, as setup (like the PRT transfer): not one of the per-packet stages.
            self.coeffs = sh.project_equirect(*_lighting_arrays(lighting), bands=max_bands)
            self._use_coefficients(StageTimer())

    # --- the virtual object --------------------------------------------------------------------------

    def _load_object(self) -> None:
        from rgbd_envmap import assets, prt

        oc = self.config.object
        bands = self.sh_bands_computed
        self._object = assets.load_virtual_object(oc.name, height_m=oc.height_m, cache_dir=self._cache_dir)
        self._transfer = prt.load_or_compute(self._object, bands, n_dirs=oc.prt_dirs, cache_dir=self._cache_dir)
        self._plane = prt.shadow_plane(
            self._object, size_m=oc.plane_size_m, resolution=oc.plane_resolution, bands=bands, n_dirs=oc.prt_dirs,
            cache_dir=self._cache_dir,
        )

    @property
    def virtual_object(self):
        """The :class:`~rgbd_envmap.assets.VirtualObject` being composited (object frame), or None with
        rendering off; its world position is :attr:`object_base`."""
        return self._object

    @property
    def object_base(self) -> np.ndarray:
        """(3,) world position of the object's base (moves with :meth:`move_object`)."""
        return self.capture.em.origin + self.object_offset - np.array([0.0, 0.0, self.config.object.base_below_origin_m])

    def move_object(self, offset: np.ndarray, *, permanent: bool = False) -> None:
        """Move the object by ``offset`` (metres, world) from the EM origin. Temporary: the lighting
        comes from the map translated to the new position, recomputed after each update; permanent:
        the map itself is translated (§6.2) and its origin moves."""
        off = check_array(offset, "offset", shape=(3,), finite=True).astype(np.float64)
        if permanent:
            with self.timer.stage("EM translation"):
                self.capture.em = translate(self.capture.em, self.object_offset + off, self.config.translation_method,
                                            threads=self.config.threads)
            self.object_offset = np.zeros(3)
        else:
            self.object_offset = self.object_offset + off
        self._relight()

    # --- packets -------------------------------------------------------------------------------------

    def _skip(self, reason: str, n: int = 1) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + n
        if self.skipped[reason] <= 0:
            del self.skipped[reason]

    def _in_order(self, kind: str, timestamp_ns: int) -> bool:
        """False for a packet not after the previous one of its stream (skipped); counts the packets
        missing before it from the stream's rate (grid index from the first packet, so timestamp
        jitter below half a period is not a gap)."""
        rate = self.calibration.depth_rate_hz if kind == "depth" else self.calibration.colour_rate_hz
        s = self._stream.get(kind)
        if s is None:
            self._stream[kind] = [timestamp_ns, timestamp_ns, 0]
            return True
        if timestamp_ns <= s[1]:
            self._skip(f"{kind}_out_of_order")
            if self.skipped.get(f"{kind}_missing"):
                self._skip(f"{kind}_missing", -1)  # counted as missing when its successor came first
            return False
        s[1] = timestamp_ns
        if rate and rate > 0:
            index = round((timestamp_ns - s[0]) * 1e-9 * rate)
            if index > s[2] + 1:
                self._skip(f"{kind}_missing", index - s[2] - 1)
            s[2] = max(index, s[2])
        return True

    def _check_pose(self, timestamp_ns: int, T_world_from_colour: np.ndarray) -> None:
        """Flags a jump of the device's reported pose since the previous packet's (see PoseCheckConfig)."""
        pc = self.config.pose_check
        last, self._last_pose = self._last_pose, (timestamp_ns, T_world_from_colour)
        before = self._pose_before
        if last is not None and last[0] != timestamp_ns:
            self._pose_before = last
        if last is None or not pc.enabled:
            return
        dt = abs(timestamp_ns - last[0]) * 1e-9
        a, b = last[1], T_world_from_colour
        step = a[:3, 3] - b[:3, 3]
        cos = (np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) * 0.5
        turn = math.degrees(math.acos(min(1.0, max(-1.0, cos))))
        if math.sqrt(step @ step) > pc.max_speed_m_s * dt + pc.slack_m or turn > pc.max_turn_deg_s * dt + pc.slack_deg:
            if pc.skip_frozen and before is not None and before[0] != last[0] \
                    and np.allclose(before[1], last[1], rtol=0.0, atol=FROZEN_POSE_TOL):
                # A frozen tracker catching up: the frozen side is the wrong one, so the new pose is
                # taken as it is (no hold, no map check; the frozen packets were skipped).
                self.frozen_resumes += 1
                return
            self._jumped = True
            self._jump_ns = timestamp_ns
            if pc.map_check:  # where the device would be without the jump: the motion before it, continued
                dt_prev = 0 if before is None else last[0] - before[0]
                predicted = last[1] if dt_prev <= 0 else extrapolated_pose(before[1], last[1], (timestamp_ns - last[0]) / dt_prev)
                self._correction = predicted @ np.linalg.inv(T_world_from_colour)
                self._offset_confirmed = False

    def _usable_depth(self, packet: DepthPacket) -> bool:
        """Checks of a depth packet on arrival (order, points, pose); False: skipped and counted."""
        if not self._in_order("depth", packet.timestamp_ns):
            return False
        pose = packet.T_world_from_depth.matrix
        self._check_pose(packet.timestamp_ns, pose @ self._colour_from_depth)
        frozen = self._last_depth_pose is not None and np.array_equal(pose, self._last_depth_pose)
        self._last_depth_pose = pose
        if len(packet.points_m) == 0:
            self._skip("depth_no_points")
            return False
        if frozen and self.config.pose_check.enabled and self.config.pose_check.skip_frozen:
            self._skip("depth_pose_frozen")
            return False
        return True

    def _pose_jumped(self, timestamp_ns: int) -> bool:
        """A jump since the last depth step, or within ``pose_check.jump_hold_s`` before this packet:
        the depth packet about to be processed is skipped."""
        held = self._jump_ns is not None and timestamp_ns - self._jump_ns < self.config.pose_check.jump_hold_s * 1e9
        if not (self._jumped or held):
            return False
        self._jumped = False
        self._skip("depth_pose_jump")
        return True

    def _inconsistent_with_map(self, depth: DepthPacket) -> bool:
        """The map check (``pose_check.map_check``), after a pose jump: a subsample of the packet's
        points against the map's distances in their directions
        (:func:`~rgbd_envmap.pipeline.consistency.map_consistency`), placed once by the reported pose
        and once with the jump undone (the motion before the jump, continued). When the undone pose
        agrees with the map on ``map_margin`` × the probed points more than the reported one, the
        jump is the tracker's error: this packet and every one up to the next jump (the snap back)
        are skipped and counted, without further tests (an offset packet let in would make the map
        agree with the offset). When the reported pose agrees better by that margin, the jump was
        real (e.g. a frozen tracker catching up) and the check ends. Without a verdict (fewer than
        ``map_min_compared`` points on the map, as where the device first sees a part of the room,
        or neither pose ahead by the margin) the packet is skipped too, and the next one tested:
        a reported pose stays suspect until the map vouches for it.
        ``map_accept_after_s`` after the jump the check ends either way, and the offset is taken as
        the truth."""
        pc = self.config.pose_check
        self.map_consistency = None
        C = self._correction
        if C is None or not (pc.enabled and pc.map_check) or not self.capture.has_reference or not len(depth.points_m):
            return False
        accept = pc.map_accept_after_s
        if accept is not None and self._jump_ns is not None and depth.timestamp_ns - self._jump_ns >= accept * 1e9:
            self._correction = None  # a relocalisation that lasts: the map is what is wrong
            self.map_check_accepted += 1
            return False
        if self._offset_confirmed:
            self._skip("depth_inconsistent_with_map")
            return True
        step = max(1, len(depth.points_m) // pc.map_check_points)
        T = depth.T_world_from_depth
        undone = RigidTransform(C @ T.matrix, T.dst, T.src)
        rep, cor = (map_consistency(self.capture.em, depth.points_m, pose, step=step, tol_m=pc.map_tol_m, tol_rel=pc.map_tol_rel)
                    for pose in (T, undone))
        self.map_consistency = (rep, cor)
        margin = pc.map_margin * rep.sampled
        judged = max(rep.compared, cor.compared) >= pc.map_min_compared
        if judged and rep.consistent - cor.consistent > margin:
            self._correction = None  # the reported pose is the right one
            return False
        # The undone pose fits better (the offset is confirmed), or no verdict yet (too little of the
        # map in view, or the offset does not show against it): the reported pose stays suspect.
        self._offset_confirmed = judged and cor.consistent - rep.consistent > margin
        self._skip("depth_inconsistent_with_map")
        return True

    def _frozen_frame(self, nv21: np.ndarray) -> bool:
        prev, self._prev_nv21 = self._prev_nv21, nv21
        if prev is None or prev.shape != nv21.shape:
            return False
        # A strided probe first: two different frames differ within a few hundred bytes.
        return bool(np.array_equal(prev.reshape(-1)[::257], nv21.reshape(-1)[::257]) and np.array_equal(prev, nv21))

    def feed(self, packet: DepthPacket | ColourPacket) -> list[DepthStep | ColourStep]:
        """Process one packet; returns what it produced (a depth step and / or a composited frame).
        Packets it cannot use are skipped and counted in :attr:`skipped`."""
        check_instance(packet, (DepthPacket, ColourPacket), "packet")
        if self._merger is not None:
            raise InvalidInputError("feed: a 'kinect' pipeline takes registered RGB-D frames; use feed_rgbd")
        lag_ns = self.config.max_colour_lag_ms * 1e6
        out: list[DepthStep | ColourStep] = []
        if isinstance(packet, DepthPacket):
            if not self._usable_depth(packet):
                return out
            if self._pending_depth is not None:  # its colour frame never came: the nearest earlier one, or dropped
                self._resolve_pending(None, out)
            last = self._last_colour
            if last is not None and abs(last[0].timestamp_ns - packet.timestamp_ns) <= lag_ns:
                self._pair(packet, last, out)
            else:
                self._pending_depth, self._pending_partner = packet, last
            return out
        if not self._in_order("colour", packet.timestamp_ns):
            return out
        self._check_pose(packet.timestamp_ns, packet.T_world_from_colour.matrix)
        colour_frame = self.timer.begin("colour")
        t0 = time.perf_counter()
        srgb8 = decode_nv21(packet.nv21, packet.height, packet.width)
        self._decode_ms = (time.perf_counter() - t0) * 1e3
        self.timer.add("Decode colour frame", self._decode_ms)
        if self._frozen_frame(packet.nv21):
            self._skip("colour_frozen_frame")
            out.append(ColourStep(packet.timestamp_ns, None, srgb8))
            return out
        self._last_colour = (packet, srgb8)
        bracket = packet.bracketed and self.config.hdr.enabled
        pending = self._pending_depth
        if pending is not None:
            ahead = packet.timestamp_ns - pending.timestamp_ns
            if abs(ahead) <= lag_ns:
                self._pending_depth = self._pending_partner = None
                self._pair(pending, (packet, srgb8), out, resume=colour_frame)
            elif ahead > lag_ns:  # the stream has passed the depth packet: the nearer of this and the one before
                self._resolve_pending((packet, srgb8), out, resume=colour_frame)
            elif self._pending_partner is None or -ahead < abs(self._pending_partner[0].timestamp_ns - pending.timestamp_ns):
                self._pending_partner = (packet, srgb8)  # an earlier frame delivered late
        if bracket:  # HDR capture: an exposure bracket's frame goes into the map only, never on screen
            self.bracketed_frames += 1
            return out
        out.append(self._colour_step(packet, srgb8))
        return out

    def _pair(self, depth: DepthPacket, colour: tuple[ColourPacket, np.ndarray], out: list,
              resume: int | None = None) -> None:
        """Run the depth step of ``depth`` with ``colour`` (packet, decoded sRGB) unless a pose jump
        holds it; ``resume``: the colour frame whose timing record continues afterwards."""
        if self._pose_jumped(depth.timestamp_ns) or self._inconsistent_with_map(depth):
            return
        self.timer.begin("depth")
        out.append(self._depth_step(depth, colour[0], colour[1]))
        if resume is not None:
            self.timer.resume(resume, "colour")

    def _resolve_pending(self, after: tuple[ColourPacket, np.ndarray] | None, out: list,
                         resume: int | None = None) -> None:
        """The pending depth packet's own colour frame will not come (lost, frozen or too late): it
        pairs with the nearer of the usable frame before it and ``after`` (the first one past the
        lag) if within ``colour_fallback_lag_ms``, else it is dropped and counted."""
        depth, self._pending_depth = self._pending_depth, None
        before, self._pending_partner = self._pending_partner, None
        fallback = self.config.colour_fallback_lag_ms
        best = None
        if fallback is not None:
            for c in (before, after):
                gap = None if c is None else abs(c[0].timestamp_ns - depth.timestamp_ns)
                if gap is not None and gap <= fallback * 1e6 and (best is None or gap < best[0]):
                    best = (gap, c)
        if best is None:
            self.dropped_depth += 1
            self._skip("depth_no_colour")
            return
        self.late_pairs += 1
        self._pair(depth, best[1], out, resume)

    def finish(self) -> list[DepthStep]:
        """End of stream: a depth packet still waiting for its colour frame pairs with the nearest
        earlier one within ``colour_fallback_lag_ms``, or is dropped (counted). Returns the depth
        step it made, if any."""
        out: list[DepthStep] = []
        if self._pending_depth is not None:
            self._resolve_pending(None, out)
        return out

    def feed_rgbd(self, timestamp_ns: int, rgb_srgb8: np.ndarray, depth_m: np.ndarray, known: np.ndarray,
                  T_world_from_cam) -> list[DepthStep | ColourStep]:
        """Process one registered RGB-D frame of a Kinect-like sensor (paper 001 §4.2): warp the
        previous filtered depth into this view and merge it with the new depth, then the same stages
        as a Tango frame (reliability, correction, EM, SH, shading), then composite this frame.

        Args:
            rgb_srgb8: (H, W, 3) uint8 sRGB colour, registered to the depth (one pixel grid).
            depth_m: (H, W) float z-depth in metres, meaningful where ``known``.
            known: (H, W) bool.
            T_world_from_cam: the camera's pose (RigidTransform).
        """
        if self._merger is None:
            raise InvalidInputError(f"feed_rgbd needs a 'kinect' calibration, got {self.calibration.sensor!r}")
        t = self.timer
        cfg = self.config
        t.begin("depth")
        with t.stage("Warp + merge depth (Kinect)"):
            merged = self._merger.step(depth_m, known, T_world_from_cam)
        out: list[DepthStep | ColourStep] = []
        self._kinect_frames += 1
        if (self._kinect_frames - 1) % cfg.kinect_em_every == 0:
            self.depth_steps += 1
            s = cfg.kinect_em_stride
            intr = self.calibration.depth
            if s > 1:
                intr = dataclasses.replace(intr, width=len(range(0, intr.width, s)), height=len(range(0, intr.height, s)),
                                           fx=intr.fx / s, fy=intr.fy / s, cx=intr.cx / s, cy=intr.cy / s)
            with t.stage("Depth image to RGB-D"):
                frame = kinect_rgbd_frame(merged.depth_m[::s, ::s], merged.known[::s, ::s], np.asarray(rgb_srgb8)[::s, ::s],
                                          T_world_from_cam, intr, timestamp_ns)
            raw = np.where(known, depth_m, 0).astype(np.float32)[::s, ::s]
            out.append(self._capture_and_relight(frame, frame, depth_m=raw, known=np.asarray(known)[::s, ::s]))
        t.begin("colour")
        out.append(self._render(int(timestamp_ns), T_world_from_cam, np.asarray(rgb_srgb8)))
        return out

    def _depth_step(self, depth: DepthPacket, colour: ColourPacket, srgb8: np.ndarray) -> DepthStep:
        from rgbd_envmap.depth import mark_reliable
        from rgbd_envmap.depth.denoise import denoise_frame

        cfg = self.config
        t = self.timer
        cal = self.calibration
        self.depth_steps += 1
        # The paired colour frame was decoded once, on arrival; its time counts in this frame too.
        t.add("YUV420 to linear RGB", self._decode_ms)
        with t.stage("Point cloud to RGB-D"):
            frame, _ = rgbd_frame_from_packets(depth, srgb8, colour.T_world_from_colour, cal, cfg.ingest)
        if cfg.ingest.denoise_half_window is not None:
            with t.stage("Denoise depth"):
                frame = denoise_frame(frame, half_window=cfg.ingest.denoise_half_window,
                                      tol_rel=cfg.ingest.denoise_tol_rel, min_inliers=cfg.ingest.denoise_min_inliers)
        bracket = cfg.hdr.enabled and colour.bracketed
        with t.stage("Mark reliable RGB-D"):  # on the sensor's values: the exposure rule is about them
            dark = {"dark": cfg.hdr.bracket_dark} if bracket else {}
            reliable = mark_reliable(frame.rgb, frame.depth_m, frame.known, method=cfg.ingest.reliability_method, **dark)
        decoded, scale = frame, 1.0
        if cfg.hdr.enabled:  # HDR capture (docs/design/hdr.md): clip flags; a bracket frame at the live exposure
            with t.stage("HDR exposure + clip flags"):
                scale = exposure_scale(self._matrix_exposure, colour.exposure) if bracket else 1.0
                frame = hdr_frame(decoded, scale, self._low_confidence(decoded.rgb, bracket))
        across = None
        if cfg.ingest.fill_method is None:
            filled = frame
        else:
            with t.stage("Hole filling RGB-D"):
                d, k, across = cfg.ingest.fill(frame.depth_m, frame.known)
                m_cd = registration_matrix(depth, colour.T_world_from_colour, cal, cfg.ingest.registration)
                filled = colour_filled(decoded, d, k, srgb8, m_cd, cal.colour)
            if cfg.hdr.enabled:
                with t.stage("HDR exposure + clip flags"):
                    filled = hdr_frame(filled, scale, self._low_confidence(filled.rgb, bracket))
        live_matrix = self.capture.matrix
        # a bracket frame's colours are at the live exposure (the matrix's) by now
        exposure = self._matrix_exposure if bracket else colour.exposure
        # A bracket frame is fitted and gated like a live one (projecting it with the matrix in force,
        # ungated, broke the matrix's chain after a dropout burst: docs/design/hdr.md).
        out = self._capture_and_relight(frame, filled, reliable=reliable, across_edges=across, exposure=exposure,
                                        white_balance=colour.white_balance)
        if bracket:  # a bracket frame's fit does not steer the live frames' correction (nor their composites)
            self.capture.matrix = live_matrix
        elif out.capture.reference or (out.capture.ccm is not None and out.capture.ccm.accepted):
            self._matrix_exposure = colour.exposure  # the exposure the matrix in force was fitted at
        return replace(out, timestamp_ns=depth.timestamp_ns, colour_timestamp_ns=colour.timestamp_ns, exposure_scale=scale)

    def _low_confidence(self, rgb: np.ndarray, bracket: bool) -> np.ndarray:
        """HDR capture's flags (docs/design/hdr.md): pixels with a clipped channel and, in a bracket
        frame, those darker than ``hdr.bracket_dark`` in every channel (the live frames measure them
        better); the map never lets such a sample overwrite an unflagged colour of its surface."""
        hdr = self.config.hdr
        return low_confidence_pixels(rgb, hdr.clip_level, hdr.bracket_dark if bracket else None)

    def _capture_and_relight(self, frame: RGBDFrame, filled: RGBDFrame, *, reliable: np.ndarray | None = None,
                             depth_m: np.ndarray | None = None, known: np.ndarray | None = None,
                             across_edges: np.ndarray | None = None, exposure: float | None = None,
                             white_balance: tuple[float, float, float] | None = None) -> DepthStep:
        """Reliability (unless given), correction + EM update, SH and shading of one ingested frame.
        ``depth_m`` / ``known``: the sensor's own measurement when ``frame`` is already a merge of it;
        ``across_edges``: the hole filling's flags (:class:`rgbd_envmap.ingest.tango.TangoIngestResult`);
        ``exposure``: the colour frame's exposure time × ISO, None where unknown; ``white_balance``: its
        white-balance gains, None where unknown."""
        from rgbd_envmap.depth import mark_reliable

        t = self.timer
        if reliable is None:
            with t.stage("Mark reliable RGB-D"):
                reliable = mark_reliable(frame.rgb, frame.depth_m, frame.known, method=self.config.ingest.reliability_method)
        step = self.capture.process(frame, reliable, filled, across_edges=across_edges, timer=t, exposure=exposure,
                                    white_balance=white_balance)
        sh_updated = False
        if not self.fixed_lighting and (step.projected or not self.has_lighting):
            if self.capture.em.valid.any():
                self._relight()
                sh_updated = True
        raw_depth = frame.depth_m if depth_m is None else depth_m
        raw_known = frame.known if known is None else known
        return DepthStep(frame.timestamp_ns, frame.timestamp_ns, step, raw_depth, raw_known,
                         filled.depth_m, filled.known, sh_updated, self.bands)

    def _lighting_map(self) -> EnvironmentMap:
        if not self.object_offset.any():
            return self.capture.em
        with self.timer.stage("EM translation"):
            # Into last frame's view: its arrays are already paged in (a fresh 34 MB map costs page faults).
            self._translated = translate(self.capture.em, self.object_offset, self.config.translation_method,
                                         out=self._translated, threads=self.config.threads)
            return self._translated

    def _relight(self) -> None:
        """SH coefficients of the (possibly translated) map → band choice → shading of the object
        (nothing to do with fixed lighting: its shading was set up at construction)."""
        if self.fixed_lighting:
            return
        em = self._lighting_map()
        if not em.valid.any():
            return
        with self.timer.stage("Calculate SH coefficients*"):
            self.coeffs = self._projection.coefficients(em)
        if self._differential:
            with self.timer.stage("Lights from the map"):
                self._split_lighting(em)
        self._use_coefficients(self.timer)

    @property
    def _differential(self) -> bool:
        """The differential composite runs: asked for, with the captured map (its depth) and an object."""
        rc = self.config.render
        return rc.enabled and rc.composite == "differential" and not self.fixed_lighting and self._object is not None

    def _split_lighting(self, em: EnvironmentMap) -> None:
        """The map's direct part as lights with positions, the indirect rest as SH (paper 000 §4.2):
        ``self.lights`` and ``self.coeffs_indirect`` = the coefficients minus the direct pixels' own."""
        from rgbd_envmap.lights import (AreaLightState, HemigonState, LightSet, Q2TreeState, direct_part, light_grid,
                                        sample_lights)

        rc = self.config.render
        # On every render.light_grid_stride-th row and column (4: a 16th of the pixels, the split's
        # histogram and the sampler cost about that much less; a lamp spans tens of pixels). Radiance
        # clamped at 0 (the correction matrix can leave tiny negative values).
        k = rc.light_grid_stride
        sub = (slice(k // 2, None, k), slice(k // 2, None, k))
        radiance = light_grid(em.radiance, k)
        valid = np.ascontiguousarray(em.valid[sub])
        # with the direct pixels' own SH coefficients (the basis from its separable factors)
        direct, _, sh_direct = direct_part(radiance, rc.tau, self.sh_bands_computed, valid=valid)
        ind = self.coeffs - sh_direct
        self.coeffs_indirect = ind
        last = self._lights_sh
        if self.lights is not None and last is not None and last.shape == sh_direct.shape and direct.any():
            ref = float(np.linalg.norm(last))
            if ref > 0 and float(np.linalg.norm(sh_direct - last)) <= rc.lights_tolerance * ref:
                self.lights_kept += 1  # the same lights (and, in the shader, their shadow terms)
                return
        self.lights = None
        self._lights_sh = sh_direct
        if direct.any():
            if self._light_state is None and rc.light_method != "pharr":
                self._light_state = {"q2tree": Q2TreeState, "hemigon": HemigonState, "val": AreaLightState}[rc.light_method]()
            options = {"points": rc.light_points} if rc.light_method == "val" else {}
            self.lights = sample_lights(radiance, rc.lights, rc.light_method, valid=direct,
                                        depth_m=np.ascontiguousarray(em.depth_m[sub]), origin=em.origin,
                                        state=self._light_state, **options)
            keep = self.lights.power.max(axis=1) > 0
            if not keep.all():
                L = self.lights
                self.lights = LightSet(L.directions[keep], L.power[keep], L.method,
                                       solid_angle=None if L.solid_angle is None else L.solid_angle[keep],
                                       positions=None if L.positions is None else L.positions[keep],
                                       origin=L.origin, points=None if L.points is None else L.points[keep],
                                       point_power=None if L.point_power is None else L.point_power[keep])

    def _use_coefficients(self, timer: StageTimer) -> None:
        """Band choice and shading of the object from ``self.coeffs``."""
        self.has_lighting = True
        sc = self.config.shading
        if sc.auto_bands and self._transfer is not None:
            with timer.stage("Select SH bands"):
                if self._gram is None:
                    self._gram = sh.transfer_gram(self._transfer)  # once per object, not per selection
                self.bands = sh.select_bands(self.coeffs, self._gram, tolerance=sc.band_tolerance, max_bands=sc.max_bands).bands
        if self._object is not None:
            self._shade(timer)

    def _shade(self, timer: StageTimer) -> None:
        from rgbd_envmap import prt

        n = self.bands * self.bands
        differential = self._differential and self.coeffs_indirect is not None
        if not differential or self.config.render.object_shading == "prt":
            with timer.stage("Shade object (PRT)"):
                if self._shade_out is None:
                    self._shade_out = np.empty((len(self._transfer), 3), np.float32)
                # A fresh buffer per call, not the one the renderer may still hold: swap two buffers.
                self._shade_out, out = self.colours, self._shade_out
                self.colours = prt.shade(self._transfer[:, :n], self.coeffs[:n], self._object.albedo, out=out)
                if not differential:  # the differential composite's receivers replace the plane
                    self.plane_alpha = prt.shadow_alpha(self._plane, self.coeffs[:n])
        if differential:
            self._shade_differential(timer, n)

    def _shade_differential(self, timer: StageTimer, n: int) -> None:
        """The object's radiance from lights (self-shadowed) + indirect PRT, and the receivers' ratio
        E_with / E_without (rgbd_envmap.render.differential); the receiver mesh is rebuilt from the map's
        depth every ``render.geometry_every`` relights."""
        from rgbd_envmap.render.differential import DifferentialShader
        from rgbd_envmap.render.geometry import surface_radiance

        rc = self.config.render
        base = self.object_base
        if self._diff_shader is None or not np.array_equal(base, self._diff_base):
            self._diff_shader = DifferentialShader(self._object.vertices.astype(np.float64) + base, self._object.faces,
                                                   self._object.normals, samples=rc.occlusion_samples)
            self._diff_base = base.copy()
            self._relights_since_geometry = rc.geometry_every
        shader = self._diff_shader
        if self._relights_since_geometry >= rc.geometry_every:
            with timer.stage("Receiver geometry"):
                em = self._lighting_map()
                # the first mesh is needed now; later ones are built from a snapshot of the map's depth
                # and used geometry_lag relights on (on the second core meanwhile, with two threads)
                lag = rc.geometry_lag if len(shader.receivers) else 0
                snapshot = (em.depth_m.copy(), em.valid.copy(), em.origin.copy()) if lag else \
                    (em.depth_m, em.valid, em.origin)
                build = functools.partial(_receiver_geometry, *snapshot, shader, base.copy(), rc, self.sh_bands_computed,
                                          own_occluder=lag > 0)
                if lag and self.config.threads >= 2:
                    if self._geometry_pool is None:
                        from concurrent.futures import ThreadPoolExecutor

                        self._geometry_pool = ThreadPoolExecutor(1, thread_name_prefix="rgbd-envmap-geometry")
                    job = self._geometry_pool.submit(build)
                else:
                    job = _Done(build())
                self._geometry_job = (job, shader, lag)
            self._relights_since_geometry = 0
        pending = self._geometry_job
        if pending is not None and pending[1] is not shader:
            self._geometry_job = pending = None  # built for an object that has moved since: dropped
        if pending is not None and self._relights_since_geometry >= pending[2]:
            with timer.stage("Receiver geometry"):
                mesh, occlusion = pending[0].result()
                em = self._lighting_map()
                radiance = surface_radiance(em.radiance, em.valid, em.origin, mesh.vertices) if rc.max_albedo else None
                shader.set_receivers(mesh, self.sh_bands_computed, radiance=radiance, max_albedo=rc.max_albedo or 1.0,
                                     occlusion=occlusion)
            self._geometry_job = None
        self._relights_since_geometry += 1
        with timer.stage("Shade receivers" if rc.object_shading == "prt" else "Shade object (PRT)"):
            # "prt": the object keeps its PRT colours (self.colours), which also light the receivers
            fixed = self.colours if rc.object_shading == "prt" else None
            self.colours, self.receiver_ratio = shader.shade(self.lights, self.coeffs_indirect[:n], self._transfer,
                                                             self._object.albedo, object_colours=fixed,
                                                             object_coeffs=None if fixed is None else self.coeffs[:n])
            self._receiver_faces = shader.active_faces(self.receiver_ratio)

    def _colour_step(self, packet: ColourPacket, srgb8: np.ndarray) -> ColourStep:
        return self._render(packet.timestamp_ns, packet.T_world_from_colour, srgb8)

    def _render(self, timestamp_ns: int, T_world_from_colour, srgb8: np.ndarray) -> ColourStep:
        if not self.config.render.enabled or self.colours is None:
            return ColourStep(timestamp_ns, None, srgb8)
        from rgbd_envmap import render

        if self._renderer is None:
            self._renderer = render.Renderer(self.calibration.colour, backend=self.config.render.backend)
        base = self.object_base
        receivers = None
        differential = self._differential and self.receiver_ratio is not None and len(self._diff_shader.receivers)
        with self.timer.stage("Rasterise"):
            if differential:
                # the receivers (map mesh + the support plane) replace the paper-003 plane; only their
                # triangles whose ratio differs from 1 change a pixel
                none = (np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros(0))
                layer = self._renderer.render(T_world_from_colour, self._object.vertices + base, self._object.faces,
                                              self.colours, *none)
                receivers = self._renderer.render(T_world_from_colour, self._diff_shader.receivers.vertices,
                                                  self._receiver_faces, self.receiver_ratio, *none)
            else:
                layer = self._renderer.render(
                    T_world_from_colour,
                    self._object.vertices + base, self._object.faces, self.colours,
                    self._plane.vertices + base, self._plane.faces, self.plane_alpha,
                )
        with self.timer.stage("Composite"):
            if receivers is None:
                image = render.composite(srgb8, layer, ccm_inverse=np.linalg.inv(self.capture.matrix),
                                         shadow_grey=self.config.render.shadow_grey)
            else:
                image = render.composite_differential(srgb8, layer, receivers,
                                                      ccm_inverse=np.linalg.inv(self.capture.matrix),
                                                      shadow_grey=self.config.render.shadow_grey)
        return ColourStep(timestamp_ns, image, srgb8)

    def close(self) -> None:
        if self._geometry_pool is not None:
            self._geometry_pool.shutdown(wait=True)
            self._geometry_pool = None
            self._geometry_job = None
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> "Pipeline":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

