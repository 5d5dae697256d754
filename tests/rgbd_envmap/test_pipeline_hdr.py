"""HDR capture in the pipeline: bracketed colour frames go into the map, never on screen, brought to
the live exposure; with HDR off they are ordinary frames again."""

from dataclasses import replace

import numpy as np
import pytest

from rgbd_envmap.colour import HDRConfig
from rgbd_envmap.pipeline import ColourStep, DepthStep, Pipeline, PipelineConfig, RenderConfig
from rgbd_envmap.pipeline.capture import CaptureConfig
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory

ORIGIN = np.array([0.0, 0.0, 0.8])
CFG = PipelineConfig(capture=CaptureConfig(height=250, width=500), render=RenderConfig(enabled=False))


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_scene("office_unlit"), load_trajectory("orbit"),
                     TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180)), seed=2)


@pytest.fixture(scope="module")
def sim_packets(sim):
    return list(sim.run(1.0))


@pytest.fixture(scope="module")
def packets(sim_packets):
    return [sp.packet for sp in sim_packets]


def _run(sim, packets, cfg):
    pipe = Pipeline(cfg, sim.calibration, ORIGIN)
    out = [r for p in packets for r in pipe.feed(p)]
    pipe.finish()
    return pipe, [r for r in out if isinstance(r, DepthStep)], [r for r in out if isinstance(r, ColourStep)]


def test_bracketed_frames_are_fused_not_shown(sim, sim_packets, packets):
    bracket_ns = {p.timestamp_ns for p in packets if p.kind == "colour" and p.bracketed}
    assert len(bracket_ns) == 2  # −4 and −2 EV, colour frames 18 and 24
    gains = {sp.packet.timestamp_ns: sp.groundtruth["gains"] for sp in sim_packets if sp.packet.kind == "colour"}
    pipe, depth, colour = _run(sim, packets, CFG)
    assert pipe.bracketed_frames == 2 and len(colour) == 28
    assert not {c.timestamp_ns for c in colour} & bracket_ns
    fused = [d for d in depth if d.colour_timestamp_ns in bracket_ns]
    assert len(fused) == 2
    # brought to the exposure of the live frame whose matrix is in force: 2^4 and 2^2 times the
    # auto-exposure's drift since that frame
    exposure = {p.timestamp_ns: p.exposure for p in packets if p.kind == "colour"}
    matrix_exposure = None
    for d in depth:
        if d in fused:
            assert d.exposure_scale == pytest.approx(matrix_exposure / exposure[d.colour_timestamp_ns], rel=1e-12)
        else:
            assert d.exposure_scale == 1.0
            if d.capture.reference or (d.capture.ccm is not None and d.capture.ccm.accepted):
                matrix_exposure = exposure[d.colour_timestamp_ns]
    assert [d.exposure_scale for d in fused] == [pytest.approx(16.0, rel=0.3), pytest.approx(4.0, rel=0.3)]
    # The fit of each frame, bracket frames on colours brought to the live exposure, against the
    # true matrix (the gains of the reference frame over this frame's, over the scale). In this dim
    # room the −4 EV frame's pairs are near its dark level: its fit is off by about 13 %
    # (docs/design/hdr.md, "What is still wrong"), the others within 5 %.
    g_ref = gains[depth[0].colour_timestamp_ns]
    for d in depth[1:]:
        assert d.capture.projected
        true = np.diag(g_ref / gains[d.colour_timestamp_ns]) / d.exposure_scale
        err = np.linalg.norm(d.capture.matrix - true) / np.linalg.norm(true)
        assert err < (0.2 if d is fused[0] else 0.05)


def test_bracket_fit_does_not_steer_the_live_correction(sim, packets):
    pipe = Pipeline(CFG, sim.calibration, ORIGIN)
    for p in packets:
        before = pipe.capture.matrix.copy()
        steps = [r for r in pipe.feed(p) if isinstance(r, DepthStep)]
        if steps and steps[0].exposure_scale != 1.0:
            np.testing.assert_array_equal(pipe.capture.matrix, before)


def test_hdr_off_treats_bracketed_frames_as_live(sim, packets):
    pipe, depth, colour = _run(sim, packets, replace(CFG, hdr=HDRConfig(enabled=False)))
    assert pipe.bracketed_frames == 0 and len(colour) == 30
    assert all(d.exposure_scale == 1.0 for d in depth)

