import dataclasses

import numpy as np
import pytest

from rgbd_envmap.colour import decode_nv21, linear_to_srgb
from rgbd_envmap.errors import RangeError
from rgbd_envmap.geometry import look_at
from sim.colour_camera import AutoExposureState, ColourCameraConfig, capture_colour
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
