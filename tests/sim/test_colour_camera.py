import dataclasses

import numpy as np
import pytest

from rgbd_envmap.colour import decode_nv21, linear_to_srgb
from rgbd_envmap.errors import RangeError
from rgbd_envmap.geometry import look_at
from sim.colour_camera import AutoExposureState, ColourCameraConfig, capture_colour
from sim.device import TangoDeviceConfig
from sim.raycast import SceneRaycaster
from sim.session import Simulator
from sim.trajectory import load_trajectory

SMALL = dict(width=160, height=120)
#: NV21 round trip (YUV rounding) is within 2 codes on flat colour; noise adds a little more.
CODE_TOL = 2


def _flat_pixels(radiance: np.ndarray) -> np.ndarray:
    """Pixels whose 5×5 neighbourhood has one radiance, so 4:2:0 chroma subsampling cannot blur them."""
    h, w, _ = radiance.shape
    flat = np.zeros((h, w), bool)
    pad = np.pad(radiance, ((2, 2), (2, 2), (0, 0)), mode="edge")
    same = np.ones((h, w), bool)
    for dy in range(5):
        for dx in range(5):
            same &= np.all(pad[dy:dy + h, dx:dx + w] == radiance, axis=-1)
    flat[2:-2, 2:-2] = same[2:-2, 2:-2]
    return flat


@pytest.mark.parametrize("noise", [False, True])
def test_pixel_equals_radiance_times_gains_after_decoding(office, noise):
    cfg = ColourCameraConfig(**SMALL, shot_noise=2e-4 if noise else 0.0, read_noise=1e-3 if noise else 0.0)
    state = AutoExposureState(exposure=1.7, white_balance=(1.2, 1.0, 0.8))
    T = look_at([0.5, 0.5, 1.2], [-1.0, -2.0, 1.3])  # towards the poster and the south wall
    cap = capture_colour(SceneRaycaster(office), T, 0.0, cfg, state, np.random.default_rng(0))
    np.testing.assert_allclose(cap.gains, [2.04, 1.7, 1.36])
    decoded = decode_nv21(cap.nv21, cfg.height, cfg.width).astype(np.int32)
    expected = np.round(linear_to_srgb(np.clip(cap.radiance * cap.gains, 0, 1)) * 255).astype(np.int32)
    flat = _flat_pixels(cap.radiance)
    assert flat.sum() > 2000
    err = (decoded[flat] - expected[flat]).astype(np.float64)
    if not noise:
        assert np.abs(err).max() <= CODE_TOL
        return
    # Predicted noise in 8-bit codes: σ_lin = sqrt(shot·s + read²) through the sRGB slope at s.
    s = np.clip(cap.radiance[flat] * cap.gains, 1e-4, 1.0)
    slope = np.where(s <= 0.0031308, 12.92, 1.055 / 2.4 * s ** (1 / 2.4 - 1)) * 255
    sigma_code = np.sqrt(cfg.shot_noise * s + cfg.read_noise**2) * slope
    unsaturated = s < 0.95
    rms = np.sqrt(np.mean(err[unsaturated] ** 2))
    predicted = np.sqrt(np.mean(sigma_code[unsaturated] ** 2))
    # Zero-mean linear noise through the concave sRGB curve biases codes slightly low (Jensen).
    assert np.all(np.abs(err.mean(axis=0)) < 0.5)
    assert 0.6 * predicted < rms < 1.2 * np.hypot(predicted, CODE_TOL)


def test_auto_exposure_moves_more_than_2x_from_dark_corner_to_window(office):
    sim = Simulator(office, load_trajectory("sweep"), seed=1)
    sim.device = dataclasses.replace(sim.device, colour=ColourCameraConfig(**SMALL))
    gains = {}
    for sp in sim.run(10.0):
        if sp.packet.kind == "colour":
            gains[round(sp.t_s, 3)] = sp.groundtruth["gains"]
    corner, window = gains[2.9], gains[max(gains)]
    assert np.mean(corner) / np.mean(window) > 2.0


def test_exposure_reacts_with_lag():
    cfg = ColourCameraConfig(**SMALL)
    bright = np.full((500, 3), 0.9)
    state = AutoExposureState(exposure=8.0)
    history = [state.exposure]
    for _ in range(60):
        state = state.update(bright, cfg)
        history.append(state.exposure)
    steps = np.abs(np.diff(np.log(history)))
    assert np.all(steps <= cfg.ae_rate * np.log(8.0 / 0.2) + 1e-12)  # never jumps to the target
    assert history[1] > 4.0  # the frame after the change is still far too bright
    assert history[-1] == pytest.approx(0.2, rel=0.05)  # settles: mean luma 0.9 · 0.2 = 0.18


def test_white_balance_converges_to_grey_world():
    cfg = ColourCameraConfig(**SMALL, auto_exposure=False)
    bluish = np.tile([0.1, 0.2, 0.4], (500, 1))
    state = AutoExposureState()
    for _ in range(200):
        state = state.update(bluish, cfg)
    balanced = bluish[0] * np.asarray(state.white_balance)
    np.testing.assert_allclose(balanced, balanced[1], rtol=1e-3)


def test_controls_off_keep_unit_gains():
    cfg = ColourCameraConfig(**SMALL, auto_exposure=False, auto_white_balance=False)
    state = AutoExposureState().update(np.full((100, 3), 0.01), cfg)
    np.testing.assert_array_equal(state.gains, [1.0, 1.0, 1.0])


def test_zero_size_image_is_a_clear_error():
    with pytest.raises(RangeError, match="width"):
        ColourCameraConfig(width=0, height=120).intrinsics


# --- exposure bracketing (HDR capture) -------------------------------------------------------------


def test_bracket_schedule_ends_each_run_and_frame_zero_is_live():
    cfg = ColourCameraConfig(**SMALL)  # default: −4 and −2 EV, 6 frames apart, once every 30 frames
    brackets = {i: cfg.bracket_at(i) for i in range(95) if cfg.bracket_at(i) is not None}
    assert brackets == {18: -4.0, 24: -2.0, 48: -4.0, 54: -2.0, 78: -4.0, 84: -2.0}
    assert all(i % 6 == 0 for i in brackets)  # each on a ToF frame at 30 / 5 Hz
    assert ColourCameraConfig(**SMALL, bracket_every=0).bracket_at(18) is None
    with pytest.raises(RangeError, match="bracket_every"):
        ColourCameraConfig(bracket_every=10, bracket_stride=6)  # two frames 6 apart do not fit in 10


def test_exposure_time_times_iso_is_the_gain():
    cfg = ColourCameraConfig(**SMALL)
    for gain in (0.05, 1.0, 3.0, 40.0):
        t, iso = cfg.exposure_time_iso(gain)
        assert t <= 1.0 / cfg.rate_hz + 1e-15 and t * iso == pytest.approx(gain, rel=1e-12)
    assert cfg.exposure_time_iso(1.0) == pytest.approx((0.01, 100.0))


def test_bracket_frame_is_exposed_off_the_auto_exposure_and_leaves_it_alone(office):
    cfg = ColourCameraConfig(**SMALL, shot_noise=0.0, read_noise=0.0)
    state = AutoExposureState(exposure=1.7, white_balance=(1.2, 1.0, 0.8))
    T = look_at([0.5, 0.5, 1.2], [-1.0, -2.0, 1.3])
    rc = SceneRaycaster(office)
    live = capture_colour(rc, T, 0.0, cfg, state, np.random.default_rng(0))
    low = capture_colour(rc, T, 0.0, cfg, state, np.random.default_rng(0), -4.0)
    np.testing.assert_allclose(low.gains, live.gains / 16)
    assert low.bracketed and not live.bracketed
    assert low.next_state == state and live.next_state != state  # the bracket frame does not meter
    assert low.exposure_s * low.iso == pytest.approx(1.7 / 16) and live.exposure_s * live.iso == pytest.approx(1.7)
    expected = np.round(linear_to_srgb(np.clip(low.radiance * low.gains, 0, 1)) * 255).astype(np.int32)
    decoded = decode_nv21(low.nv21, cfg.height, cfg.width).astype(np.int32)
    flat = _flat_pixels(low.radiance)
    assert np.abs(decoded[flat] - expected[flat]).max() <= CODE_TOL


def test_session_packets_carry_exposure_and_bracket_flags(office):
    sim = Simulator(office, load_trajectory("orbit"), TangoDeviceConfig(colour=ColourCameraConfig(**SMALL)), seed=0)
    colour = [sp for sp in sim.run(1.0) if sp.packet.kind == "colour"]
    assert [i for i, sp in enumerate(colour) if sp.packet.bracketed] == [18, 24]
    for sp in colour:
        gain = sp.packet.exposure_s * sp.packet.iso
        # the packet's exposure is the truth's exposure gain (the green channel's: white balance 1)
        assert gain == pytest.approx(sp.groundtruth["gains"][1], rel=1e-9)
    live = [sp.packet.exposure for sp in colour[17:20]]
    assert colour[18].packet.exposure == pytest.approx(live[0] / 16, rel=0.2)  # the AE drifts a little
