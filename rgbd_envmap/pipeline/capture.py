"""Environment capture (paper 003 §5–§6): colour correction against the map, then the map update.

:class:`EnvironmentCapture` holds the environment map and the latest accepted colour-correction
matrix (current camera colours → reference colours). Per ingested depth packet:

1. The first frame defines the reference colour space: its matrix is the identity and it is
   projected into the empty map.
2. Later frames: pairs between the frame's *reliable* pixels (marked before hole filling) and the
   map (|depth difference| ≤ 1 cm) → a 3×3 matrix. Gate: fewer than 500 pairs or MSE > 5e-2 (or an
   ill-conditioned fit) → the previous accepted matrix stays in force for correcting colours and the
   frame is **not** projected; the step records why.
3. An accepted frame is corrected with its matrix and projected with the update rules
   (:func:`rgbd_envmap.envmap.update`): every measured pixel, and the hole-filled pixels chosen by
   ``filled_pixels`` (default, as the paper: ``"all"``). Eq. (1) averages sources on both sides
   of a depth edge, so a hole at an edge (the ToF marks mixed pixels there) gets a depth in free space
   between foreground and background; seen from the origin such a point lands on an arc across the
   background and, being closer, wins it. ``"plane_consistent"`` projects a filled pixel
   only when the filled depth passes the noise-model plane test of
   :func:`rgbd_envmap.depth.reliability.discontinuity_test` (depth only, no exposure rule: the window
   and screen must go in);
   ``"none"`` projects measurements only.

With ``colour_correction=False`` every frame is projected uncorrected (the paper's Fig. 4 left);
``freeze=True`` keeps the map as it is (a static scene already captured) and only tracks the matrix.

Where the colour frames' exposures are known (exposure time × ISO, the reference frame's and the
current one's), the matrix's overall gain is their ratio and only its white balance is fitted
(``fixed_gain``, docs/design/colour_correction.md): a change of the scene's light then reaches the map
instead of being taken for an exposure change. Unknown exposure: the paper's fit.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from rgbd_envmap.checks import check_array, check_flag, check_method, check_number, check_positive_int
from rgbd_envmap.colour import (
    CCM_METHODS,
    DEFAULT_MAX_CONDITION,
    DEFAULT_RIDGE,
    SUMS_CCM_METHODS,
    CCMResult,
    ccm_from_sums,
    estimate_ccm,
)
from rgbd_envmap.colour.ccm import GAIN_CHANNELS
from rgbd_envmap.depth.reliability import discontinuity_passed
from rgbd_envmap.errors import DTypeError, RangeError
from rgbd_envmap.envmap.map import MAP_BYTES_PER_PIXEL, MAX_MAP_PIXELS, EnvironmentMap
from rgbd_envmap.envmap.pairs import frame_pair_sums, frame_pairs, frame_samples
from rgbd_envmap.envmap.map_update import SeenDepth, UpdateConfig, UpdateStats, update
from rgbd_envmap.timing import StageTimer
from rgbd_envmap.types import RGBDFrame

__all__ = ["CaptureConfig", "CaptureStep", "EnvironmentCapture", "FILLED_PIXEL_MODES"]

FILLED_PIXEL_MODES = ("plane_consistent", "all", "none")


class _NullTimer:
    @contextmanager
    def stage(self, name: str):
        yield


_NO_TIMER = _NullTimer()


@dataclass(frozen=True)
class CaptureConfig:
    """Colour-correction and map settings (the paper's, except ``ccm_method``, ``edge_margin_px`` and
    the update's splatting, carving and averaging, which are ours)."""

    height: int = 1000
    width: int = 2000
    #: pairs need the map's depth within this distance of the sample's (metres).
    pair_max_depth_diff_m: float = 0.01
    colour_correction: bool = True
    #: "ridge" by default: plain least squares fits noise on the grey-dominated pairs of a room
    #: (docs/design/colour_correction.md); "least_squares" is the paper's fit.
    ccm_method: str = "ridge"
    max_mse: float = 5e-2
    min_pairs: int = 500
    #: with the exposures known (the reference frame's and the frame's), the matrix's gain along this
    #: channel is their ratio and only the white balance is fitted: "green" (a white balance keeps the
    #: green gain at 1), "luminance" (:data:`rgbd_envmap.colour.ccm.GAIN_CHANNELS`), or None (the gain
    #: is fitted too, the paper; as when an exposure is unknown).
    fixed_gain: str | None = "green"
    #: with the white-balance gains known too (the reference frame's and the frame's, as phones report
    #: them: :attr:`rgbd_envmap.types.ColourPacket.white_balance`), the matrix is known, not fitted:
    #: diag(reference gains / frame gains), gains = exposure × white balance. The fit above still gates
    #: the frame (``min_pairs``, ``max_mse``: a wrong pose fails it; a room whose light changed does
    #: not). False: the fitted matrix is used (docs/design/colour_correction.md).
    known_white_balance: bool = True
    update: UpdateConfig = field(default_factory=UpdateConfig)
    #: which hole-filled pixels go into the map: "all" (paper), "plane_consistent", "none". With the
    #: edge margin on, "plane_consistent" measures no better than "all".
    filled_pixels: str = "all"
    #: samples within this many frame pixels of a depth edge (a pixel failing the plane test) do not
    #: take map pixels over by the "closer" rule (they still fill empty pixels, and the trusted-sphere
    #: and removal rules still apply); None: the paper's rules. Near an
    #: object's border, depth noise scatters its samples across its silhouette seen from the origin,
    #: and "closer" keeps every one that lands on the background (a running minimum over noise).
    #: 1 px is best with the denoised depth (docs/design/envmap.md).
    edge_margin_px: int | None = 1
    freeze: bool = False

    def __post_init__(self) -> None:
        check_positive_int(self.height, "CaptureConfig.height")
        check_positive_int(self.width, "CaptureConfig.width")
        pixels = self.height * self.width
        if pixels > MAX_MAP_PIXELS:
            raise RangeError(f"CaptureConfig.height × width: {self.height}×{self.width} would take about "
                             f"{pixels * MAP_BYTES_PER_PIXEL / 2**30:.1f} GiB for the map alone; at most "
                             f"{MAX_MAP_PIXELS:,} pixels (e.g. 8192×4096)")
        check_number(self.pair_max_depth_diff_m, "CaptureConfig.pair_max_depth_diff_m", low=0.0)
        check_flag(self.colour_correction, "CaptureConfig.colour_correction")
        check_flag(self.known_white_balance, "CaptureConfig.known_white_balance")
        if not isinstance(self.update, UpdateConfig):
            raise DTypeError(f"CaptureConfig.update: expected an UpdateConfig, got {type(self.update).__name__}")
        check_number(self.edge_margin_px, "CaptureConfig.edge_margin_px", low=0, high=64, integer=True, optional=True)
        check_flag(self.freeze, "CaptureConfig.freeze")
        check_method(self.filled_pixels, FILLED_PIXEL_MODES, "filled_pixels")
        check_method(self.ccm_method, CCM_METHODS, "ccm_method")
        if self.fixed_gain is not None:
            check_method(self.fixed_gain, GAIN_CHANNELS, "CaptureConfig.fixed_gain")
        # What estimate_ccm would reject per frame, rejected once here (the fused fit skips its checks).
        check_number(self.max_mse, "CaptureConfig.max_mse", low=0.0)
        check_positive_int(self.min_pairs, "CaptureConfig.min_pairs")


@dataclass(frozen=True)
class CaptureStep:
    """What one frame did.

    Attributes:
        timestamp_ns: the frame's.
        reference: this frame defined the reference colour space.
        ccm: the fit for this frame (None for the reference frame or with correction off).
        projected: the frame went into the map.
        reason: why not, when not ("" otherwise).
        n_pairs: colour pairs found.
        matrix: (3, 3) the accepted matrix in force after this frame.
        update: what the map update did (None when not projected).
    """

    timestamp_ns: int
    reference: bool
    ccm: CCMResult | None
    projected: bool
    reason: str
    n_pairs: int
    matrix: np.ndarray
    update: UpdateStats | None


class EnvironmentCapture:
    """The environment map and the colour-correction state that feeds it."""

    def __init__(self, origin: np.ndarray, config: CaptureConfig = CaptureConfig(), *, threads: int = 2) -> None:
        """``threads``: for the colour pairs and the map update (1 or 2; the same results bit for bit)."""
        self.config = config
        self.threads = check_positive_int(threads, "threads")
        self.em = EnvironmentMap(config.height, config.width, origin)
        self.matrix = np.eye(3)
        self.has_reference = False
        #: exposure time × ISO of the reference frame, None where unknown.
        self.reference_exposure: float | None = None
        self.reference_white_balance: np.ndarray | None = None

    def process(self, raw: RGBDFrame, reliable: np.ndarray, filled: RGBDFrame, *, across_edges: np.ndarray | None = None,
                timer: StageTimer | None = None, exposure: float | None = None,
                white_balance: object = None) -> CaptureStep:
        """Process one ingested frame: ``raw`` (before hole filling) with its ``reliable`` mask, and
        ``filled`` (after hole filling), both in the current camera's colour space. ``timer`` records
        the stages "Collect paired samples", "Compute colour correction matrix" (the fit and its MSE)
        and "Project sample to EM*".

        ``across_edges``: (H, W) bool, filled pixels whose depth was interpolated across a depth edge
        (:attr:`rgbd_envmap.ingest.tango.TangoIngestResult.across_edges`). They go into the map only
        while the device is inside the trusted sphere (``config.update.trusted_radius_m`` of the
        origin). Elsewhere their depth, somewhere between a foreground and a background, would put
        them in free space, and seen from the origin they would cover what lies behind. Near the
        origin the device sees what the origin sees, and the trusted rule relies on exactly that
        (docs/design/hole_filling.md). None: every filled pixel goes in (the paper).

        ``exposure``: the frame's exposure time × ISO (:attr:`rgbd_envmap.types.ColourPacket.exposure`),
        None where unknown. With it and the reference frame's known, the matrix's gain is their ratio
        (``config.fixed_gain``). ``white_balance``: (3,) the frame's white-balance gains, None where
        unknown; with both known for the frame and the reference frame the matrix is known
        (``config.known_white_balance``)."""
        cfg = self.config
        exposure = check_number(exposure, "exposure", low=0.0, low_open=True, optional=True)
        if white_balance is not None:
            white_balance = check_array(white_balance, "white_balance", shape=(3,), dtype=("float", "int"),
                                        finite=True).astype(np.float64)
            if not (white_balance > 0).all():
                raise RangeError(f"white_balance: expected three gains > 0, got {white_balance.tolist()}")
        t = timer or _NO_TIMER
        ts = raw.timestamp_ns
        if not self.has_reference:
            if not filled.known.any():
                return CaptureStep(ts, False, None, False, "no known pixels for a reference frame", 0, self.matrix.copy(), None)
            self.has_reference = True
            self.reference_exposure = exposure
            self.reference_white_balance = white_balance
            stats = None if cfg.freeze else self._timed_project(raw, filled, np.eye(3), t, across_edges)
            return CaptureStep(ts, True, None, not cfg.freeze, "" if not cfg.freeze else "frozen", 0, self.matrix.copy(), stats)
        if not cfg.colour_correction:
            stats = None if cfg.freeze else self._timed_project(raw, filled, np.eye(3), t, across_edges)
            return CaptureStep(ts, False, None, not cfg.freeze, "" if not cfg.freeze else "frozen", 0, self.matrix.copy(), stats)
        known = None if cfg.fixed_gain is None or exposure is None or self.reference_exposure is None \
            else self.reference_exposure / exposure
        gain = {} if known is None else {"known_gain": known, "gain_channel": cfg.fixed_gain}
        if cfg.ccm_method in SUMS_CCM_METHODS:
            # The fit needs only the pairs' normal-equation sums: accumulated in the pair pass
            # (bit-identical to collecting the pairs and summing them), so no pair array is stored.
            with t.stage("Collect paired samples"):
                *sums, n_found = frame_pair_sums(self.em, raw.depth_m, reliable, raw.intrinsics, raw.T_world_from_cam,
                                                 raw.rgb, cfg.pair_max_depth_diff_m, threads=self.threads)
            with t.stage("Compute colour correction matrix"):
                ccm = ccm_from_sums(*sums, cfg.ccm_method, max_mse=cfg.max_mse, min_pairs=cfg.min_pairs,
                                    max_condition=DEFAULT_MAX_CONDITION, noise_std=None, ridge=DEFAULT_RIDGE, **gain)
        else:
            with t.stage("Collect paired samples"):
                # collect_pairs(em, frame_points(raw.depth_m, reliable, …), raw.rgb[reliable]) in one pass.
                src, dst = frame_pairs(self.em, raw.depth_m, reliable, raw.intrinsics, raw.T_world_from_cam, raw.rgb,
                                       cfg.pair_max_depth_diff_m)
                n_found = len(src)
            with t.stage("Compute colour correction matrix"):
                ccm = estimate_ccm(src, dst, method=cfg.ccm_method, max_mse=cfg.max_mse, min_pairs=cfg.min_pairs, **gain)
        if ccm.accepted and cfg.known_white_balance and exposure is not None and self.reference_exposure is not None \
                and white_balance is not None and self.reference_white_balance is not None:
            # The frame's gains against the reference frame's are known: that is the matrix. The fit
            # still gates the frame (its residual tells a wrong pose or a blurred frame; a room whose
            # light changed is still one linear map away, so it passes, and the change reaches the map).
            gains = (self.reference_exposure / exposure) * self.reference_white_balance / white_balance
            ccm = replace(ccm, matrix=np.diag(gains), method="known")
        if not ccm.accepted:
            return CaptureStep(ts, False, ccm, False, ccm.reason, n_found, self.matrix.copy(), None)
        self.matrix = np.array(ccm.matrix, dtype=np.float64)
        if cfg.freeze:
            return CaptureStep(ts, False, ccm, False, "frozen", n_found, self.matrix.copy(), None)
        stats = self._timed_project(raw, filled, self.matrix, t, across_edges)
        return CaptureStep(ts, False, ccm, True, "", n_found, self.matrix.copy(), stats)

    def projected_mask(self, raw: RGBDFrame, filled: RGBDFrame, across_edges: np.ndarray | None = None) -> np.ndarray:
        """(H, W) bool: the pixels of ``filled`` that go into the map (see ``filled_pixels`` and
        :meth:`process`'s ``across_edges``)."""
        mode = self.config.filled_pixels
        if mode == "all":
            mask = filled.known
        elif mode == "none":
            mask = raw.known & filled.known
        else:
            consistent = discontinuity_passed(filled.depth_m, filled.known)
            mask = filled.known & (raw.known | consistent)
        if across_edges is None or mode == "none":
            return mask
        across = np.asarray(across_edges)
        if across.shape != mask.shape or across.dtype != np.bool_:  # check_array's message, only when it fails
            check_array(across, "across_edges", shape=mask.shape, dtype="bool")
        o = raw.T_world_from_cam.translation - self.em.origin
        if math.sqrt(o @ o) < self.config.update.trusted_radius_m:  # rule_trusted, without a compiled call
            return mask
        return mask & ~across

    def _timed_project(self, raw: RGBDFrame, frame: RGBDFrame, matrix: np.ndarray, timer,
                       across_edges: np.ndarray | None = None) -> UpdateStats:
        with timer.stage("Project sample to EM*"):
            return self._project(raw, frame, matrix, across_edges)

    def _project(self, raw: RGBDFrame, frame: RGBDFrame, matrix: np.ndarray, across_edges: np.ndarray | None = None) -> UpdateStats:
        mask = self.projected_mask(raw, frame, across_edges)
        near_edge = None
        if self.config.edge_margin_px is not None:
            plane = discontinuity_passed(frame.depth_m, frame.known)
            edge = (frame.known & ~plane).view(np.uint8)
            k = 2 * int(self.config.edge_margin_px) + 1
            near_edge = cv2.dilate(edge, np.ones((k, k), np.uint8))
        # frame_points(frame.depth_m, mask, …), frame.rgb[mask] and near_edge[mask] in one pass,
        # and the colours corrected (apply_ccm(frame.rgb[mask], matrix), up to float32 rounding).
        pts, colours, fill_only = frame_samples(frame.depth_m, mask, frame.intrinsics, frame.T_world_from_cam, frame.rgb,
                                                near_edge, matrix)
        focal = frame.intrinsics.focal_px  # 0.5 (|fx| + |fy|): focal lengths are signed (ICL-NUIM's fy < 0)
        seen = SeenDepth(raw.depth_m, raw.known, raw.intrinsics, raw.T_world_from_cam)  # measured only
        clipped = None if frame.clipped is None else frame.clipped[mask]  # HDR clip flags, in the samples' order
        return update(self.em, pts, colours, frame.T_world_from_cam.translation, focal, self.config.update,
                      None if near_edge is None else fill_only, seen, clipped=clipped, threads=self.threads)
