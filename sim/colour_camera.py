"""Colour camera with auto-exposure and auto-white-balance that react with lag.

Image formation per frame: radiance (ray cast through each distorted pixel) × hidden per-channel
gains (exposure × white balance) → shot + read noise → clip to [0, 1] → sRGB encoding → 8-bit
quantisation → NV21 (4:2:0). The gains are the ground truth the pipeline's colour correction must undo.

Auto-exposure meters the frame it just captured (mean luminance of the clipped image) and moves the
exposure in log space a fraction ``ae_rate`` of the way to the value that would put that mean at
``ae_target``; auto-white-balance does the same towards grey-world gains. The new gains apply from the
next frame, so a change in the scene shows up first as an over/under-exposed frame, as on a phone.

**Exposure bracketing** (HDR capture, docs/design/hdr.md): each run of ``bracket_every`` colour
frames ends with a bracket, its frames ``bracket_stride`` frames apart (6 at 30 / 5 Hz: each on a
ToF frame, so each pairs with depth), exposed at ``bracket_ev`` EV from the auto-exposure; the
next run's first frame is the bracket's 0 EV frame, at the live exposure (frame 0 is live, so the
pipeline's reference frame is too). Bracket frames do not move the auto-exposure
or white balance. Each frame reports its exposure time and ISO (gain 1 is 1/100 s at ISO 100; the
time is at most one frame period, the rest is ISO), as phone cameras do.

References:
    Nikodým, Havran et al., Multiple Live Video Environment Map Sampling, §3: three exposures fused
    into one HDR light probe.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np

from rgbd_envmap.colour import encode_nv21, linear_to_srgb
from rgbd_envmap.errors import RangeError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.types import Distortion, Intrinsics, RigidTransform
from sim.raycast import SceneRaycaster

__all__ = ["ColourCameraConfig", "AutoExposureState", "ColourCapture", "colour_intrinsics", "capture_colour"]

_LUMA = np.array([0.2126, 0.7152, 0.0722])

#: Linear signal quantised to 16 bits → 8-bit sRGB code, rounded. A table lookup is ~5× faster than
#: evaluating the transfer function per pixel, and 16 bits resolve every 8-bit sRGB step (the
#: narrowest, near black, is 1/3295 of full scale).
_LUT_SIZE = 65536
SRGB8_LUT = np.round(linear_to_srgb(np.arange(_LUT_SIZE, dtype=np.float64) / (_LUT_SIZE - 1)) * 255.0).astype(np.uint8)


#: Gaussian noise is drawn from a fixed bank of standard normals at a random offset per frame:
#: drawing 6 M fresh normals per FullHD frame cost ~50 ms; the bank makes it free, and frames stay
#: independent enough for a sensor model (the offset is uniform over 2^23 values).
NOISE_BANK_SIZE = 1 << 23


@lru_cache(maxsize=1)
def noise_bank() -> np.ndarray:
    return np.random.default_rng(0x5EED).standard_normal(2 * NOISE_BANK_SIZE, dtype=np.float32)


# Serial on purpose: a parallel kernel's OpenMP threads spin after returning and slow the ray cast
# that follows (open3d runs its own thread pool); this loop is memory-bound anyway.
@numba.njit(cache=True)
def expose_quantise(radiance, gains, shot, read2, noise, lut):  # pragma: no cover - compiled
    n = radiance.shape[0]
    out = np.empty((n, 3), np.uint8)
    top = lut.shape[0] - 1
    for i in range(n):
        for c in range(3):
            s = radiance[i, c] * gains[c]
            s = min(max(s, 0.0), 1.0)
            s += np.sqrt(shot * s + read2) * noise[3 * i + c]
            code = int(s * top + 0.5)
            out[i, c] = lut[min(max(code, 0), top)]
    return out


@lru_cache(maxsize=4)
def _unit_rays_cached(intrinsics: Intrinsics) -> np.ndarray:
    rays = pixel_rays(intrinsics).reshape(-1, 3)
    return (rays / np.linalg.norm(rays, axis=1, keepdims=True)).astype(np.float32)


#: A mild phone-lens Brown distortion (k1, k2, p1, p2, k3).
DEFAULT_COLOUR_DISTORTION = Distortion(0.06, -0.12, 0.0006, -0.0004, 0.04)


def colour_intrinsics(width: int, height: int, hfov_deg: float = 78.0, distortion: Distortion | None = None) -> Intrinsics:
    """Intrinsics of the colour camera at a given resolution: square pixels, centred principal point."""
    fx = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    dist = distortion if distortion is not None else DEFAULT_COLOUR_DISTORTION
    return Intrinsics(width, height, fx, fx, (width - 1) / 2.0, (height - 1) / 2.0, dist)


@dataclass(frozen=True)
class ColourCameraConfig:
    """Colour camera and its automatic controls (defaults: FullHD at 30 Hz like the paper's device)."""

    width: int = 1920
    height: int = 1080
    #: 78° × 49° at 16:9, a typical phone main camera; it covers the ToF camera's 58.5° × 46.5°.
    hfov_deg: float = 78.0
    distortion: Distortion = DEFAULT_COLOUR_DISTORTION
    rate_hz: float = 30.0
    #: photon shot noise variance per unit signal, and read-noise σ (linear units of full scale).
    shot_noise: float = 2e-4
    read_noise: float = 1e-3
    auto_exposure: bool = True
    auto_white_balance: bool = True
    #: mean luminance the auto-exposure aims for (linear), and the fraction of the log error fixed per frame.
    ae_target: float = 0.18
    ae_rate: float = 0.15
    exposure_range: tuple[float, float] = (0.05, 40.0)
    awb_rate: float = 0.08
    wb_range: tuple[float, float] = (0.4, 2.5)
    #: metering looks at every ``meter_stride``-th pixel along each axis.
    meter_stride: int = 8
    #: exposure bracketing: EV offsets of a bracket's frames from the auto-exposure (empty: off);
    #: 0 EV is the live frame that follows.
    bracket_ev: tuple[float, ...] = (-4.0, -2.0)
    #: one bracket in every run of this many colour frames, at its end (0: off).
    bracket_every: int = 30
    #: colour frames between a bracket's frames (6: one per ToF frame at 30 / 5 Hz).
    bracket_stride: int = 6

    def __post_init__(self) -> None:
        if self.bracket_every < 0 or self.bracket_stride < 1:
            raise RangeError(f"ColourCameraConfig.bracket_every / bracket_stride: expected ≥ 0 / ≥ 1, got "
                             f"{self.bracket_every} / {self.bracket_stride}")
        if self.bracket_every and len(self.bracket_ev) * self.bracket_stride > self.bracket_every:
            raise RangeError(f"ColourCameraConfig.bracket_every: a bracket of {len(self.bracket_ev)} frames {self.bracket_stride} apart does not fit "
                             f"in bracket_every={self.bracket_every} frames")

    def bracket_at(self, index: int) -> float | None:
        """The EV offset of colour frame ``index`` when it is a bracket frame, else None."""
        if not self.bracket_every or not self.bracket_ev:
            return None
        k = index % self.bracket_every - (self.bracket_every - len(self.bracket_ev) * self.bracket_stride)
        if k < 0 or k % self.bracket_stride:
            return None
        return float(self.bracket_ev[k // self.bracket_stride])

    def exposure_time_iso(self, gain: float) -> tuple[float, float]:
        """The (exposure time in s, ISO) a phone reports for an exposure gain: gain 1 is 1/100 s at
        ISO 100; the time is capped at one frame period and ISO makes up the rest."""
        t = min(0.01 * gain, 1.0 / self.rate_hz)
        return t, gain / t

    @property
    def intrinsics(self) -> Intrinsics:
        return colour_intrinsics(self.width, self.height, self.hfov_deg, self.distortion)


@dataclass(frozen=True)
class AutoExposureState:
    """Hidden camera state: exposure gain and per-channel white-balance gains."""

    exposure: float = 1.0
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @property
    def gains(self) -> np.ndarray:
        """(3,) float64 total per-channel gain applied to radiance."""
        return self.exposure * np.asarray(self.white_balance)

    def update(self, radiance_sample: np.ndarray, config: ColourCameraConfig) -> "AutoExposureState":
        """The state for the next frame, after metering (N, 3) radiance samples of this frame."""
        exposure, wb = self.exposure, np.asarray(self.white_balance)
        if radiance_sample.size == 0:
            return self
        if config.auto_exposure:
            captured = np.clip(radiance_sample * (exposure * wb), 0.0, 1.0)
            mean_luma = max(float(np.mean(captured @ _LUMA)), 1e-4)
            step = config.ae_rate * (np.log(config.ae_target) - np.log(mean_luma))
            exposure = float(np.clip(exposure * np.exp(step), *config.exposure_range))
        if config.auto_white_balance:
            exposed = radiance_sample * self.exposure * wb
            unsaturated = np.all(exposed < 0.98, axis=1) & np.all(exposed > 0.01, axis=1)
            if unsaturated.sum() >= 16:
                means = np.mean(radiance_sample[unsaturated], axis=0)
                target = np.clip(means[1] / np.maximum(means, 1e-6), *config.wb_range)
                target[1] = 1.0
                wb = np.exp(np.log(wb) + config.awb_rate * (np.log(target) - np.log(wb)))
        return AutoExposureState(exposure, tuple(float(x) for x in wb))


@dataclass(frozen=True)
class ColourCapture:
    """One simulated colour frame: the NV21 buffer, the gains used, and the true radiance image."""

    nv21: np.ndarray
    gains: np.ndarray
    radiance: np.ndarray
    next_state: AutoExposureState
    #: exposure time (s) and ISO of the frame (their product is its exposure gain).
    exposure_s: float = 0.01
    iso: float = 100.0
    #: a bracket frame (exposed off the auto-exposure; ``ev`` of :func:`capture_colour`).
    bracketed: bool = False
    #: the per-channel white-balance gains the frame was taken with (as a phone reports them).
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)


def capture_colour(
    raycaster: SceneRaycaster,
    T_world_from_colour: RigidTransform,
    t_s: float,
    config: ColourCameraConfig,
    state: AutoExposureState,
    rng: np.random.Generator,
    ev: float | None = None,
) -> ColourCapture:
    """Render, expose, encode and meter one colour frame. ``ev``: a bracket frame, exposed at ``ev``
    EV from the auto-exposure (``config.bracket_at``); it leaves the auto-exposure and white balance
    as they are. None: a live frame."""
    intr = config.intrinsics
    dirs = _unit_rays_cached(intr)
    hits = raycaster.cast(T_world_from_colour.translation, T_world_from_colour.rotate(dirs), t_s, normals=False)
    radiance = hits.radiance.reshape(intr.height, intr.width, 3)
    n_values = radiance.size
    if n_values > NOISE_BANK_SIZE:
        noise = rng.standard_normal(n_values, dtype=np.float32)
    else:
        offset = int(rng.integers(0, NOISE_BANK_SIZE))
        noise = noise_bank()[offset:offset + n_values]
    scale = 1.0 if ev is None else 2.0 ** ev
    gains = state.gains * scale
    srgb8 = expose_quantise(
        hits.radiance, gains.astype(np.float32), np.float32(config.shot_noise),
        np.float32(config.read_noise**2), noise, SRGB8_LUT,
    ).reshape(intr.height, intr.width, 3)
    s = config.meter_stride
    if ev is None:
        next_state = state.update(radiance[::s, ::s].reshape(-1, 3).astype(np.float64), config)
    else:
        next_state = state
    exposure_s, iso = config.exposure_time_iso(state.exposure * scale)
    return ColourCapture(encode_nv21(srgb8), gains, radiance, next_state, exposure_s, iso, ev is not None,
                         tuple(float(w) for w in state.white_balance))
