"""The capture with known exposures (``CaptureConfig.fixed_gain``): the matrix's gain is the exposure
ratio, so a room that darkens reaches the map instead of the matrix; unknown exposure: the paper's fit."""

import numpy as np
import pytest

from rgbd_envmap.errors import RangeError, UnknownMethodError
from rgbd_envmap.geometry import look_at
from rgbd_envmap.pipeline.capture import CaptureConfig, EnvironmentCapture
from tests.rgbd_envmap.test_capture import _frame, colourful_room  # noqa: F401 (fixture)

SMALL = CaptureConfig(height=200, width=400, min_pairs=200)
T0 = look_at([0.0, 0.0, 0.0], [2.0, 0.1, 0.0])
T1 = look_at([0.0, 0.0, 0.0], [2.0, 0.2, 0.05])
WB = np.array([1.3, 1.0, 0.75])  # green gain 1, as a camera's white balance


def _run(room, config=SMALL, exposures=(1.0, 2.0), light=0.4):
    """Reference frame at exposure 1 and the room's light; then the room darkens to ``light`` and the
    camera doubles its exposure with a new white balance."""
    cap = EnvironmentCapture(np.zeros(3), config)
    f0 = _frame(room, T0)
    cap.process(f0, f0.known, f0, exposure=exposures[0])
    f1 = _frame(room, T1, light * 2.0 * WB, 1)
    return cap, cap.process(f1, f1.known, f1, exposure=exposures[1])


def test_a_darkened_room_is_not_taken_for_an_exposure_change(colourful_room):
    cap, step = _run(colourful_room)
    assert step.projected and cap.reference_exposure == 1.0
    true = np.diag(1.0 / (2.0 * WB))  # the camera's correction: exposure 2, white balance WB
    # 5 %: pairs straddling patch edges mismatch between the two views (as in test_capture)
    np.testing.assert_allclose(step.matrix, true, atol=0.05 * true.max())
    assert step.ccm.fitted_gain / 0.5 == pytest.approx(1.0 / 0.4, rel=0.05)
    # the map takes the darker room: the grey walls (0.4) seen by the second frame now read ≈ 0.16
    wall = cap.em.valid & (np.abs(cap.em.radiance - 0.16).max(axis=-1) < 0.03)
    assert wall.sum() > 100


@pytest.mark.parametrize("exposures", [(None, 2.0), (1.0, None), (None, None)])
def test_an_unknown_exposure_keeps_the_papers_fit(colourful_room, exposures):
    _, step = _run(colourful_room, exposures=exposures)
    _, paper = _run(colourful_room, CaptureConfig(height=200, width=400, min_pairs=200, fixed_gain=None))
    np.testing.assert_array_equal(step.matrix, paper.matrix)
    assert step.ccm == paper.ccm
    # the paper's fit absorbs the darkening: about diag(1 / (0.4 · 2 · WB))
    np.testing.assert_allclose(paper.matrix, np.diag(1.0 / (0.8 * WB)), atol=0.05 / 0.8 / WB.min())


def test_luminance_gain_channel_holds_the_luminance_response(colourful_room):
    _, step = _run(colourful_room, CaptureConfig(height=200, width=400, min_pairs=200, fixed_gain="luminance"))
    luma = np.array([0.2126, 0.7152, 0.0722])
    assert luma @ step.matrix.sum(axis=1) == pytest.approx(0.5, rel=1e-9)


def test_bad_fixed_gain_and_exposure_are_refused(colourful_room):
    with pytest.raises(UnknownMethodError, match="fixed_gain"):
        CaptureConfig(fixed_gain="blue")
    cap = EnvironmentCapture(np.zeros(3), SMALL)
    f0 = _frame(colourful_room, T0)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(RangeError, match="exposure"):
            cap.process(f0, f0.known, f0, exposure=bad)
