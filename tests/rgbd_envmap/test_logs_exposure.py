"""Colour packets' exposure metadata (HDR capture) in session logs: round trip, logs written before
the field (no colour_exposure.txt) and packets without metadata, and a broken exposure file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rgbd_envmap.errors import DTypeError, LogFormatError, RangeError
from rgbd_envmap.logs import SessionLog, SessionWriter, as_logged
from rgbd_envmap.types import ColourPacket
from tests.rgbd_envmap.test_logs import H, W, colour_packet, make_calibration


def _with_exposure(rng, ns, exposure_s, iso, bracketed):
    p = colour_packet(rng, ns)
    return ColourPacket(p.timestamp_ns, p.nv21, p.T_world_from_colour, exposure_s, iso, bracketed)


def test_exposure_metadata_round_trips_exactly(tmp_path: Path):
    rng = np.random.default_rng(3)
    packets = [_with_exposure(rng, 1_000, 1 / 30, 123.456789012345, False), colour_packet(rng, 2_000),
               _with_exposure(rng, 3_000, 0.000625, 100.0, True)]
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        for p in packets:
            w.write(p)
    log = SessionLog.open(tmp_path / "s")
    got = [log.read_colour(i) for i in range(3)]
    assert (got[0].exposure_s, got[0].iso, got[0].bracketed) == (1 / 30, 123.456789012345, False)
    assert (got[1].exposure_s, got[1].iso, got[1].bracketed) == (None, None, False)
    assert (got[2].exposure_s, got[2].iso, got[2].bracketed) == (0.000625, 100.0, True)
    assert got[2].exposure == 0.0625
    for p, g in zip(packets, got):  # as_logged predicts the read-back packet
        assert as_logged(p).exposure_s == g.exposure_s and as_logged(p).bracketed == g.bracketed


def test_a_log_without_the_exposure_file_reads_as_before(tmp_path: Path):
    # An old-format log: the writer of this version with the file removed is what older versions wrote.
    rng = np.random.default_rng(4)
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(_with_exposure(rng, 1_000, 0.01, 100.0, True))
    (tmp_path / "s" / "colour_exposure.txt").unlink()
    p = SessionLog.open(tmp_path / "s").read_colour(0)
    assert (p.exposure_s, p.iso, p.bracketed, p.exposure) == (None, None, False, None)
    assert p.nv21.shape == (H * 3 // 2, W)


def test_a_broken_exposure_line_names_the_file_and_line(tmp_path: Path):
    rng = np.random.default_rng(5)
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(_with_exposure(rng, 1_000, 0.01, 100.0, False))
    path = tmp_path / "s" / "colour_exposure.txt"
    path.write_text("0.000001000 0.01 100 yes\n")
    with pytest.raises(LogFormatError, match=r"colour_exposure.txt, line 1"):
        SessionLog.open(tmp_path / "s")


def test_packet_exposure_fields_are_checked():
    rng = np.random.default_rng(6)
    p = colour_packet(rng, 1)
    with pytest.raises(RangeError, match="exposure_s"):
        ColourPacket(1, p.nv21, p.T_world_from_colour, -1.0, 100.0)
    with pytest.raises(DTypeError, match="bracketed"):
        ColourPacket(1, p.nv21, p.T_world_from_colour, 0.01, 100.0, "yes")
