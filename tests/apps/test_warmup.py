"""apps.warmup compiles the specialisations the pipeline uses, not others."""

import numpy as np

from apps.warmup import main
from rgbd_envmap import sh
from rgbd_envmap._kernels import envmap_pairs, envmap_update, raster, sh_incremental
from rgbd_envmap.pipeline.capture import CaptureConfig, EnvironmentCapture
from rgbd_envmap.geometry import look_at
from rgbd_envmap.types import Intrinsics, RGBDFrame

KERNELS = {"update": envmap_update.update_kernel, "pairs": envmap_pairs.frame_pair_sums_kernel,
           "samples": envmap_pairs.frame_samples_kernel,
           "sh changes": sh_incremental.apply_changes, "raster": raster.raster_mesh}


def test_warmup_compiles_what_the_capture_and_sh_tracker_then_use():
    """After the warm-up, a capture of three frames and the SH tracker add no new specialisation to
    the kernels it compiles (so a first run loads them from the cache instead of compiling)."""
    assert main() == 0
    before = {name: set(k.signatures) for name, k in KERNELS.items()}
    assert all(before.values())
    rng = np.random.default_rng(1)
    intr = Intrinsics(32, 24, 28.0, 28.0, 15.5, 11.5)
    cap = EnvironmentCapture(np.zeros(3), CaptureConfig(height=50, width=100, min_pairs=10))
    tracker = sh.IncrementalProjection(5)
    base = rng.uniform(0.2, 0.8, (24, 32, 3)).astype(np.float32)
    for i, target in enumerate(([1.0, 0.1, 0.0], [1.0, 0.15, 0.02], [1.0, 0.2, 0.0])):
        T = look_at([0.0, 0.0, 0.0], target)
        frame = RGBDFrame(base, np.full((24, 32), 1.5, np.float32), np.ones((24, 32), bool), T, intr, i)
        step = cap.process(frame, frame.known.copy(), frame)  # a writable mask, as mark_reliable's
        assert step.projected, step.reason
        tracker.coefficients(cap.em)
    assert tracker.incremental_updates > 0
    assert {name: set(k.signatures) for name, k in KERNELS.items()} == before


def test_warmup_compiles_what_the_differential_composite_then_uses():
    """After the warm-up, a short session composited by the differential composite (the default)
    adds no new specialisation to the relight's and the composite's kernels."""
    from rgbd_envmap._kernels import differential, lights_split, occlusion_rays, receiver_shading
    from rgbd_envmap.pipeline import ColourStep, ObjectConfig, Pipeline, PipelineConfig, RenderConfig
    from sim.colour_camera import ColourCameraConfig
    from sim.device import TangoDeviceConfig
    from sim.scene import load_scene
    from sim.session import Simulator
    from sim.trajectory import load_trajectory

    kernels = {"receiver ratio": receiver_shading.receiver_ratio_kernel, "faces": receiver_shading.faces_touching_kernel,
               "cone rays": occlusion_rays.cone_rays_kernel, "ray SH sums": occlusion_rays.ray_sh_sums_kernel,
               "composite": differential.composite_differential, "split": lights_split.direct_split,
               "light grid": lights_split.clamped_subgrid}
    assert main() == 0
    before = {name: set(k.signatures) for name, k in kernels.items()}
    assert all(before.values()), before
    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit_inward"),
                    TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180)), seed=4)
    cfg = PipelineConfig(render=RenderConfig(enabled=True, backend="numba"),
                         object=ObjectConfig(name="blob", prt_dirs=128, plane_resolution=16))
    with Pipeline(cfg, sim.calibration, np.array([0.0, 0.0, 0.8])) as pipe:
        frames = [r for sp in sim.run(0.5) for r in pipe.feed(sp.packet) if isinstance(r, ColourStep)]
    assert any(f.image is not None for f in frames) and pipe.receiver_ratio is not None
    assert {name: set(k.signatures) for name, k in kernels.items()} == before
