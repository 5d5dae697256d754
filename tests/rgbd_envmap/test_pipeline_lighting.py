"""Pipeline with a fixed lighting map (``lighting=`` or ``shading.lighting_file``): the object is
shaded by PRT with that map's SH coefficients, projected once, while the map is still captured.

References: ``sh.project_equirect`` of the lighting map, and ``prt.shade`` / ``prt.shadow_alpha`` with the
transfer of the same object computed by ``prt.load_or_compute`` / ``prt.shadow_plane`` here.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rgbd_envmap import assets, prt, sh
from rgbd_envmap.envmap import EnvironmentMap
from rgbd_envmap.envmap_io import to_convention, write_envmap
from rgbd_envmap.errors import InvalidInputError, UnknownMethodError
from rgbd_envmap.geometry import equirect_directions
from rgbd_envmap.pipeline import DepthStep, ObjectConfig, Pipeline, PipelineConfig, RenderConfig, ShadingConfig
from rgbd_envmap.pipeline.capture import CaptureConfig
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory

ORIGIN = np.array([0.0, 0.0, 0.8])
OBJECT = ObjectConfig(name="blob", prt_dirs=256, plane_resolution=12)
CFG = PipelineConfig(capture=CaptureConfig(height=100, width=200), object=OBJECT)


@pytest.fixture(scope="module")
def sim():
    return Simulator(load_scene("office_unlit"), load_trajectory("orbit"), TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180)), seed=3)


def sky(H=64, W=128):
    """A map with a bright patch towards +y and a dim blue sky above; part of the ground missing."""
    d = equirect_directions(H, W).astype(np.float64)
    rad = np.empty((H, W, 3))
    rad[...] = np.where(d[..., 2:] > 0, [0.2, 0.3, 0.6], [0.3, 0.25, 0.2])
    rad += 8.0 * (d[..., 1:2] > 0.9) * np.array([1.0, 0.9, 0.7])
    valid = ~((d[..., 2] < -0.8) & (d[..., 0] > 0))
    return rad.astype(np.float32), valid


def reference_shading(cfg, coeffs, cache_dir):
    obj = assets.load_virtual_object(cfg.object.name, height_m=cfg.object.height_m, cache_dir=cache_dir)
    bands = max(cfg.shading.bands, cfg.shading.max_bands if cfg.shading.auto_bands else 1)
    transfer = prt.load_or_compute(obj, bands, n_dirs=cfg.object.prt_dirs, cache_dir=cache_dir)
    plane = prt.shadow_plane(obj, size_m=cfg.object.plane_size_m, resolution=cfg.object.plane_resolution, bands=bands,
                             n_dirs=cfg.object.prt_dirs, cache_dir=cache_dir)
    n = cfg.shading.bands ** 2
    return prt.shade(transfer[:, :n], coeffs[:n], obj.albedo), prt.shadow_alpha(plane, coeffs[:n])


@pytest.mark.parametrize("form", ["envmap", "pair", "array"])
def test_shading_equals_prt_with_the_lighting_maps_sh(sim, tmp_path, form):
    rad, valid = sky()
    if form == "envmap":
        lighting = EnvironmentMap.from_arrays(rad, np.ones(valid.shape, np.float32), valid, ORIGIN)
    elif form == "pair":
        lighting = (rad, valid)
    else:
        lighting, valid = rad, None
    pipe = Pipeline(CFG, sim.calibration, ORIGIN, cache_dir=tmp_path, lighting=lighting)
    coeffs = sh.project_equirect(rad, valid, 5)
    assert pipe.fixed_lighting and pipe.has_lighting
    np.testing.assert_array_equal(pipe.coeffs, coeffs)
    colours, alpha = reference_shading(CFG, coeffs, tmp_path)
    np.testing.assert_array_equal(pipe.colours, colours)
    np.testing.assert_array_equal(pipe.plane_alpha, alpha)
    assert not pipe.timer.records  # set up before any packet: nothing in the run's timings
    # the bright patch towards +y: the object's +y side is brighter (Y_1,-1 ∝ −y carries it)
    assert coeffs[1, 0] < 0


def test_the_map_is_still_captured_but_the_lighting_stays_fixed(sim, tmp_path):
    rad, valid = sky()
    cfg = replace(CFG, render=RenderConfig(enabled=False), shading=ShadingConfig(bands=3))
    pipe = Pipeline(cfg, sim.calibration, ORIGIN, cache_dir=tmp_path, lighting=(rad, valid))
    coeffs = pipe.coeffs.copy()
    steps = [r for sp in sim.run(1.0) for r in pipe.feed(sp.packet)]
    depth = [s for s in steps if isinstance(s, DepthStep)]
    assert len(depth) == 5 and sum(s.capture.projected for s in depth) >= 4
    assert pipe.capture.em.valid.any()  # captured as ever
    assert not any(s.sh_updated for s in depth)
    np.testing.assert_array_equal(pipe.coeffs, coeffs)
    stages = {r.stage for r in pipe.timer.records}
    assert "Project sample to EM*" in stages and "Calculate SH coefficients*" not in stages
    # the captured map's own SH differ: the file's lighting really replaced it
    assert not np.allclose(sh.project_equirect(pipe.capture.em.radiance, pipe.capture.em.valid, 3), coeffs[:9])
    pipe.move_object(np.array([0.05, 0.0, 0.0]))  # distant lighting: moving the object changes nothing
    np.testing.assert_array_equal(pipe.coeffs, coeffs)


@pytest.mark.parametrize("convention", ["ours", "blender", "mitsuba"])
def test_lighting_file_from_the_config_in_any_convention(sim, tmp_path, convention):
    rad, valid = sky()
    path = write_envmap(tmp_path / f"sky_{convention}.exr", rad, valid, convention=convention)
    cfg = replace(CFG, shading=ShadingConfig(lighting_file=str(path)))  # the convention the file records
    pipe = Pipeline(cfg, sim.calibration, ORIGIN, cache_dir=tmp_path)
    np.testing.assert_array_equal(pipe.coeffs, sh.project_equirect(rad, valid, 5))
    # a foreign file with no record of its orientation: the convention comes from the config
    from rgbd_envmap.envmap_io import write_exr

    foreign = write_exr(tmp_path / "foreign.exr", to_convention(rad, convention), to_convention(valid, convention))
    cfg = replace(CFG, render=RenderConfig(enabled=False),
                  shading=ShadingConfig(lighting_file=str(foreign), lighting_convention=convention))
    pipe = Pipeline(cfg, sim.calibration, ORIGIN)
    np.testing.assert_array_equal(pipe.coeffs, sh.project_equirect(rad, valid, 5))


def test_auto_bands_select_once_from_the_fixed_lighting(sim, tmp_path):
    rad, valid = sky()
    cfg = replace(CFG, shading=ShadingConfig(bands=5, auto_bands=True, band_tolerance=0.05, max_bands=6))
    pipe = Pipeline(cfg, sim.calibration, ORIGIN, cache_dir=tmp_path, lighting=(rad, valid))
    coeffs = sh.project_equirect(rad, valid, 6)
    np.testing.assert_array_equal(pipe.coeffs, coeffs)
    obj = assets.load_virtual_object("blob", height_m=cfg.object.height_m, cache_dir=tmp_path)
    gram = sh.transfer_gram(prt.load_or_compute(obj, 6, n_dirs=cfg.object.prt_dirs, cache_dir=tmp_path))
    assert pipe.bands == sh.select_bands(coeffs, gram, tolerance=0.05, max_bands=6).bands


def test_bad_lighting_fails_clearly(sim, tmp_path):
    with pytest.raises(InvalidInputError, match="lighting"):
        Pipeline(CFG, sim.calibration, ORIGIN, cache_dir=tmp_path, lighting=[1, 2, 3])
    with pytest.raises(InvalidInputError, match="no such file"):
        Pipeline(replace(CFG, shading=ShadingConfig(lighting_file=str(tmp_path / "none.exr"))), sim.calibration, ORIGIN)
    with pytest.raises(UnknownMethodError, match="lighting_convention"):
        ShadingConfig(lighting_convention="unity")
    with pytest.raises(InvalidInputError, match="lighting_file"):
        ShadingConfig(lighting_file="")
