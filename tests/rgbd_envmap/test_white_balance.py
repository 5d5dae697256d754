"""Known white balance (``CaptureConfig.known_white_balance``): colour packets carry the camera's
white-balance gains, logs keep them, and with the exposure they make the correction matrix known
(diag(reference gains / frame gains)); the fit still gates the frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rgbd_envmap.errors import LogFormatError, RangeError, ShapeError
from rgbd_envmap.logs import SessionLog, SessionWriter, as_logged
from rgbd_envmap.pipeline.capture import CaptureConfig, EnvironmentCapture
from rgbd_envmap.types import ColourPacket
from tests.rgbd_envmap.test_capture import _frame, colourful_room  # noqa: F401 (fixture)
from tests.rgbd_envmap.test_ccm_exposure_capture import SMALL, T0, T1, WB
from tests.rgbd_envmap.test_logs import colour_packet, make_calibration


def _with_wb(rng, ns, wb, exposure=(0.01, 100.0)):
    p = colour_packet(rng, ns)
    return ColourPacket(p.timestamp_ns, p.nv21, p.T_world_from_colour, *exposure, False, wb)


def test_white_balance_round_trips_exactly_and_old_logs_read_as_unknown(tmp_path: Path):
    rng = np.random.default_rng(7)
    packets = [_with_wb(rng, 1_000, (1.0 / 3.0, 1.0, 2.718281828459045)), colour_packet(rng, 2_000),
               _with_wb(rng, 3_000, (0.5, 1.25, 1.0), exposure=(None, None))]
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        for p in packets:
            w.write(p)
    log = SessionLog.open(tmp_path / "s")
    got = [log.read_colour(i) for i in range(3)]
    assert got[0].white_balance == (1.0 / 3.0, 1.0, 2.718281828459045)
    assert got[1].white_balance is None
    assert got[2].white_balance == (0.5, 1.25, 1.0) and got[2].exposure is None  # independent of the exposure
    for p, g in zip(packets, got):  # as_logged predicts the read-back packet
        assert as_logged(p).white_balance == g.white_balance
    (tmp_path / "s" / "colour_white_balance.txt").unlink()  # a log written before the field
    assert SessionLog.open(tmp_path / "s").read_colour(0).white_balance is None


def test_a_broken_white_balance_line_names_the_file_and_line(tmp_path: Path):
    rng = np.random.default_rng(8)
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(_with_wb(rng, 1_000, (1.0, 1.0, 1.0)))
    path = tmp_path / "s" / "colour_white_balance.txt"
    path.write_text("0.000001000 1.0 one 1.0\n")
    with pytest.raises(LogFormatError, match=r"colour_white_balance.txt, line 1"):
        SessionLog.open(tmp_path / "s")
    path.write_text("0.000001000 1.0 0 1.0\n")  # a zero gain: an invalid packet, named
    with pytest.raises(LogFormatError, match=r"white_balance"):
        SessionLog.open(tmp_path / "s").read_colour(0)


@pytest.mark.parametrize("wb, error", [((1.0, 1.0), ShapeError), ((1.0, 0.0, 1.0), RangeError),
                                       ((1.0, -2.0, 1.0), RangeError), ((1.0, np.nan, 1.0), Exception),
                                       ((1.0, np.inf, 1.0), Exception)])
def test_packet_white_balance_is_checked(wb, error):
    rng = np.random.default_rng(9)
    with pytest.raises(error, match="white_balance"):
        _with_wb(rng, 1_000, wb)


def test_known_white_balance_gives_the_cameras_matrix_and_the_map_the_darker_room(colourful_room):
    """Reference frame at exposure 1, white balance 1; the room darkens to 0.4, the camera doubles its
    exposure and changes its white balance to WB: the matrix is exactly diag(1 / (2 WB))."""
    cap = EnvironmentCapture(np.zeros(3), SMALL)
    f0 = _frame(colourful_room, T0)
    cap.process(f0, f0.known, f0, exposure=1.0, white_balance=(1.0, 1.0, 1.0))
    f1 = _frame(colourful_room, T1, 0.4 * 2.0 * WB, 1)
    step = cap.process(f1, f1.known, f1, exposure=2.0, white_balance=WB)
    assert step.projected and step.ccm.method == "known"
    np.testing.assert_allclose(step.matrix, np.diag(1.0 / (2.0 * WB)), rtol=1e-15)
    assert step.ccm.fitted_gain / 0.5 == pytest.approx(1.0 / 0.4, rel=0.05)  # the free fit saw the darkening
    wall = cap.em.valid & (np.abs(cap.em.radiance - 0.16).max(axis=-1) < 0.03)
    assert wall.sum() > 100
    # off, or either white balance unknown: fitted (with the exposure's gain), as before the field
    for cfg, wb0, wb1 in ((CaptureConfig(height=200, width=400, min_pairs=200, known_white_balance=False), (1.0,) * 3, WB),
                          (SMALL, None, WB), (SMALL, (1.0,) * 3, None)):
        c = EnvironmentCapture(np.zeros(3), cfg)
        c.process(f0, f0.known, f0, exposure=1.0, white_balance=wb0)
        s = c.process(f1, f1.known, f1, exposure=2.0, white_balance=wb1)
        assert s.ccm.method == "ridge" and not np.array_equal(s.matrix, step.matrix)
        np.testing.assert_allclose(s.matrix, step.matrix, atol=0.05 * step.matrix.max())  # within the fit's error


def test_a_frame_the_fit_rejects_is_rejected_with_its_white_balance_known(colourful_room):
    cap = EnvironmentCapture(np.zeros(3), CaptureConfig(height=200, width=400, min_pairs=200))
    f0 = _frame(colourful_room, T0)
    cap.process(f0, f0.known, f0, exposure=1.0, white_balance=(1.0, 1.0, 1.0))
    f1 = _frame(colourful_room, T1, 0.4 * 2.0 * WB, 1)
    # a frame whose colours no matrix maps onto the map's (shuffled pixels: a wrong pose, say)
    rgb = f1.rgb.reshape(-1, 3)[np.random.default_rng(11).permutation(f1.rgb.shape[0] * f1.rgb.shape[1])]
    bad = f1.__class__(**{**f1.__dict__, "rgb": rgb.reshape(f1.rgb.shape)})
    step = cap.process(bad, bad.known, bad, exposure=2.0, white_balance=WB)
    assert not step.projected and step.ccm.method == "ridge" and step.ccm.reason.startswith("mse")
    with pytest.raises(RangeError, match="white_balance"):
        cap.process(f1, f1.known, f1, exposure=2.0, white_balance=(1.0, 0.0, 1.0))
