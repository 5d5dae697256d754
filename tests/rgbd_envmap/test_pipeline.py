"""Pipeline: packet pairing, stage timing, options; rendering is covered once the object loads."""

from dataclasses import replace

import numpy as np
import pytest

from rgbd_envmap.pipeline.capture import CaptureConfig
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError
from rgbd_envmap.pipeline import RENDER_STAGES, STAGES, ColourStep, DepthStep, ObjectConfig, Pipeline, PipelineConfig, RenderConfig
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory

ORIGIN = np.array([0.0, 0.0, 0.8])
CFG = PipelineConfig(capture=CaptureConfig(height=250, width=500), render=RenderConfig(enabled=False))


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_scene("office_unlit"), load_trajectory("orbit"), TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180)), seed=2)


@pytest.fixture(scope="module")
def packets(sim):
    return [sp.packet for sp in sim.run(1.0)]


def run(sim, packets, cfg=CFG):
    pipe = Pipeline(cfg, sim.calibration, ORIGIN)
    out = [r for p in packets for r in pipe.feed(p)]
    pipe.finish()
    return pipe, out


def test_every_depth_packet_runs_with_its_colour_frame(sim, packets):
    pipe, out = run(sim, packets)
    depth = [r for r in out if isinstance(r, DepthStep)]
    colour = [r for r in out if isinstance(r, ColourStep)]
    # 30 colour frames, two of them an exposure bracket (HDR capture: into the map, not composited)
    assert len(depth) == 5 and len(colour) == 28 and pipe.bracketed_frames == 2 and pipe.dropped_depth == 0
    assert depth[0].capture.reference and all(d.timestamp_ns == d.colour_timestamp_ns for d in depth)
    assert sum(d.capture.projected for d in depth) >= 4
    assert pipe.capture.em.valid.any() and pipe.has_lighting
    assert np.abs(pipe.coeffs).max() > 0 and pipe.coeffs.shape == (25, 3)
    stages = {r.stage for r in pipe.timer.records}
    assert stages <= set(STAGES)
    assert {"Point cloud to RGB-D", "Collect paired samples", "Project sample to EM*", "Calculate SH coefficients*"} <= stages
    # render stages only in colour frames, pipeline stages only in depth frames
    assert all(r.kind == "colour" for r in pipe.timer.records if r.stage in RENDER_STAGES)
    assert all(r.kind == "depth" for r in pipe.timer.records if r.stage not in RENDER_STAGES)


def test_order_of_depth_and_colour_with_equal_timestamps_does_not_matter(sim, packets):
    swapped = list(packets)
    for i in range(len(swapped) - 1):
        a, b = swapped[i], swapped[i + 1]
        if a.kind == "depth" and b.kind == "colour" and a.timestamp_ns == b.timestamp_ns:
            swapped[i], swapped[i + 1] = b, a
    p1, _ = run(sim, packets)
    p2, _ = run(sim, swapped)
    np.testing.assert_array_equal(p1.capture.em.radiance, p2.capture.em.radiance)
    np.testing.assert_array_equal(p1.coeffs, p2.coeffs)


def test_depth_packet_without_a_colour_frame_is_dropped_and_counted(sim, packets):
    no_colour_at_depth = [p for p in packets if not (p.kind == "colour" and p.timestamp_ns in {q.timestamp_ns for q in packets if q.kind == "depth"})]
    pipe, out = run(sim, no_colour_at_depth, replace(CFG, max_colour_lag_ms=5.0, colour_fallback_lag_ms=None))
    assert not any(isinstance(r, DepthStep) for r in out)
    assert pipe.dropped_depth == 5 and not pipe.capture.em.valid.any()
    # with the fallback (default 50 ms), a depth packet whose own colour frame is lost waits and pairs
    # with the nearer neighbour, 33 ms away
    pipe, out = run(sim, no_colour_at_depth, replace(CFG, max_colour_lag_ms=5.0))
    assert sum(isinstance(r, DepthStep) for r in out) == 5 and pipe.late_pairs == 5 and pipe.dropped_depth == 0
    # with a lag allowance of one colour period (33 ms) the next colour frame pairs
    pipe, out = run(sim, no_colour_at_depth, replace(CFG, max_colour_lag_ms=40.0))
    assert sum(isinstance(r, DepthStep) for r in out) == 5


def test_freeze_and_correction_off(sim, packets):
    frozen, _ = run(sim, packets, replace(CFG, capture=replace(CFG.capture, freeze=True)))
    assert not frozen.capture.em.valid.any()
    assert not any(r.stage.startswith("Project sample") for r in frozen.timer.records)
    off, out = run(sim, packets, replace(CFG, capture=replace(CFG.capture, colour_correction=False)))
    assert not any(r.stage == "Collect paired samples" for r in off.timer.records)
    assert all(d.capture.projected for d in out if isinstance(d, DepthStep))


def test_move_object_temporary_and_permanent(sim, packets):
    pipe, _ = run(sim, packets)
    before = pipe.capture.em.radiance.copy()
    c0 = pipe.coeffs.copy()
    pipe.move_object(np.array([0.1, 0.0, 0.0]))
    np.testing.assert_array_equal(pipe.capture.em.radiance, before)  # temporary: the stored map is intact
    assert not np.allclose(pipe.coeffs, c0)
    np.testing.assert_allclose(pipe.object_base, ORIGIN + [0.1, 0, -0.05])
    c_temp = pipe.coeffs.copy()
    pipe.move_object(np.zeros(3), permanent=True)
    np.testing.assert_allclose(pipe.capture.em.origin, ORIGIN + [0.1, 0, 0])
    np.testing.assert_allclose(pipe.coeffs, c_temp, rtol=1e-6, atol=1e-9)
    assert any(r.stage == "EM translation" for r in pipe.timer.records)


def test_bad_inputs(sim):
    with pytest.raises(InvalidInputError, match="origin"):
        Pipeline(CFG, sim.calibration, np.array([0.0, np.nan, 0.0]))
    with pytest.raises(InvalidInputError, match="translation_method"):
        PipelineConfig(translation_method="nope")
    with pytest.raises(RangeError, match="PipelineConfig.threads"):
        PipelineConfig(threads=0)
    pipe = Pipeline(CFG, sim.calibration, ORIGIN)
    with pytest.raises(DTypeError, match="packet"):
        pipe.feed("not a packet")


def test_composites_draw_the_lit_object_with_its_shadow_over_the_frame():
    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit_inward"), TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180)), seed=4)
    cfg = replace(CFG, render=RenderConfig(enabled=True, backend="numba"),
                  object=ObjectConfig(name="blob", prt_dirs=128, plane_resolution=16))
    pipe = Pipeline(cfg, sim.calibration, ORIGIN)
    frames = [r for sp in sim.run(0.5) for r in pipe.feed(sp.packet) if isinstance(r, ColourStep)]
    assert len(frames) == 15 and all(f.image is not None and f.image.shape == (180, 320, 3) for f in frames)
    changed = [np.any(f.image != f.frame_srgb, axis=-1) for f in frames]
    assert all(c.sum() > 50 for c in changed)  # the object covers pixels in every frame
    # the changed pixels sit where the object's base projects
    from rgbd_envmap.geometry import project_points

    T = sim.true_pose_colour(0.0)
    pc = (np.linalg.inv(T.matrix) @ np.append(pipe.object_base + [0, 0, 0.03], 1.0))[:3]
    uv, ok = project_points(pc[None], sim.calibration.colour)
    rows, cols = np.nonzero(changed[0])
    assert ok[0] and rows.min() - 5 <= uv[0, 1] <= rows.max() + 5 and cols.min() - 5 <= uv[0, 0] <= cols.max() + 5
    assert pipe.colours is not None and np.isfinite(pipe.colours).all() and (pipe.colours >= 0).all()
    # the default (differential) composite: the receivers under the object are in its shadow
    assert pipe.plane_alpha is None and pipe.receiver_ratio.min() < 0.7
    assert {"Rasterise", "Composite", "Shade object (PRT)", "Shade receivers"} <= {r.stage for r in pipe.timer.records}
    pipe.close()


def test_auto_bands_picks_the_fewest_bands_within_tolerance(sim, packets):
    from rgbd_envmap.pipeline import ShadingConfig

    cfg = replace(CFG, shading=ShadingConfig(bands=5, auto_bands=True, band_tolerance=0.05, max_bands=6),
                  object=ObjectConfig(name="blob", prt_dirs=128, plane_resolution=8))
    pipe, out = run(sim, packets, cfg)
    assert pipe.coeffs.shape == (36, 3) and 1 <= pipe.bands <= 6
    assert any(r.stage == "Select SH bands" for r in pipe.timer.records)
    strict, _ = run(sim, packets, replace(cfg, shading=replace(cfg.shading, band_tolerance=1e-9)))
    assert strict.bands >= pipe.bands


@pytest.mark.parametrize("tolerance", [0.0, 1.0])
def test_lights_are_kept_while_the_direct_part_stays_within_tolerance(tolerance):
    """render.lights_tolerance: 0 samples the lights on every relight; 1 keeps the lights while the
    direct part's SH stays within 100 % of theirs (the first frames' map, still filling, changes more)."""
    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit_inward"), TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180)), seed=4)
    cfg = replace(CFG, render=RenderConfig(enabled=True, backend="numba", lights_tolerance=tolerance),
                  object=ObjectConfig(name="blob", prt_dirs=128, plane_resolution=16))
    pipe = Pipeline(cfg, sim.calibration, ORIGIN)
    seen = []
    for sp in sim.run(1.0):
        for r in pipe.feed(sp.packet):
            if isinstance(r, DepthStep) and r.sh_updated and pipe.lights is not None:
                seen.append(pipe.lights)
    assert len(seen) >= 3
    distinct = len({id(s) for s in seen})
    assert distinct == len(seen) - pipe.lights_kept  # a kept relight keeps the very same light set
    assert (pipe.lights_kept == 0) == (tolerance == 0.0)
    assert np.isfinite(pipe.receiver_ratio).all()
    pipe.close()


def _rebuilds(threads: int, every: int, lag: int):
    """(relight at which each receiver mesh was installed, its size), and the final shading."""
    from rgbd_envmap.render.differential import DifferentialShader

    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit_inward"),
                    TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180)), seed=4)
    cfg = replace(CFG, threads=threads, render=RenderConfig(enabled=True, backend="numba", geometry_every=every,
                                                            geometry_lag=lag),
                  object=ObjectConfig(name="blob", prt_dirs=128, plane_resolution=16))
    installed, relights = [], [0]
    original = DifferentialShader.set_receivers

    def spy(self, receivers, *a, **k):
        installed.append((relights[0], len(receivers)))
        return original(self, receivers, *a, **k)

    DifferentialShader.set_receivers = spy
    try:
        with Pipeline(cfg, sim.calibration, ORIGIN) as pipe:
            for sp in sim.run(2.0):
                for r in pipe.feed(sp.packet):
                    if isinstance(r, DepthStep) and r.sh_updated:
                        relights[0] += 1  # counted after the relight ran
            return installed, (pipe.colours.copy(), pipe.receiver_ratio.copy())
    finally:
        DifferentialShader.set_receivers = original


def test_receiver_rebuilds_are_used_geometry_lag_relights_after_their_snapshot():
    """render.geometry_lag: the first receiver mesh is built and used at once; each later rebuild
    snapshots the map every geometry_every relights and is installed geometry_lag relights on (built
    on a second thread with two threads, at the snapshot with one: the same meshes and shading)."""
    every, lag = 3, 2
    one, shading_one = _rebuilds(1, every, lag)
    two, shading_two = _rebuilds(2, every, lag)
    at = [i for i, _ in two]
    assert len(at) >= 3 and at[0] == 0
    assert at[1:] == [every * j + lag for j in range(1, len(at))]
    assert all(n > 0 for _, n in two)
    assert one == two
    for x, y in zip(shading_one, shading_two):
        np.testing.assert_array_equal(x, y)
    now, _ = _rebuilds(2, every, 0)  # lag 0: built and used in the same relight
    assert [i for i, _ in now] == [every * j for j in range(len(now))]


def test_geometry_lag_is_less_than_the_rebuild_period():
    with pytest.raises(RangeError, match="geometry_lag"):
        RenderConfig(geometry_every=3, geometry_lag=3)
    assert RenderConfig(geometry_every=1, geometry_lag=0).geometry_lag == 0
