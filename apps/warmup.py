"""Compile the pipeline's largest numba kernels into numba's on-disk cache, for a first run.

On a fresh machine the main job spent about 60 s compiling numba kernels one after the other on one
core (map update 12 s, SH tracker 9.5 s, colour pairs 4.6 s, ...; numba's compile events), while the
other core idled. ``scripts/main.sh`` starts this module in the background when the cache is cold, so
that these kernels compile on the other core while the main process builds the simulator and compiles
its own; when the main process reaches a kernel already compiled here, numba loads it from the cache.
Both processes take a lock per kernel while compiling it (:mod:`apps.compile_once`), so a kernel
one of them is compiling is loaded by the other when it is done, never compiled twice.
The inputs are tiny but have the pipeline's dtypes and layouts, so the same specialisations are cached.
Nothing else is written; a failure here only means the main process compiles the kernel itself.

    python -m apps.warmup
"""

from __future__ import annotations

from apps.process import configure_process


def main() -> int:
    """Run each kernel on a 16×12 frame and a 40×20 map, the kernels the main process reaches last
    first: it compiles the ingest kernels and the map update of its first depth frame itself (about
    40 s in a traced cold run); meanwhile this compiles the renderer, which it reaches at the first
    composited colour frame after that, and the differential composite's kernels (its composite,
    the receivers' shading and occlusion rays, the lights), then the colour pairs and fit and the SH
    tracker, which it reaches at the second depth frame, and last the update, which by then it loads.
    With the update first (the earlier order), a traced cold run showed the update unfinished when
    the main process reached it, and the pairs compiled by both processes. The differential step
    (about 12 s of compiling) measured a cold 4 s session at 68.2 and 65.0 s against 77.0 and 66.0 s
    without it: within the machine's noise to 9 s less."""
    configure_process()  # before numpy and the library load
    import numpy as np

    from apps.compile_once import install_from_env
    from rgbd_envmap import assets, prt, render
    from rgbd_envmap.colour import DEFAULT_MAX_CONDITION, DEFAULT_RIDGE, ccm_from_sums
    from rgbd_envmap.envmap import EnvironmentMap, SeenDepth, frame_pair_sums, frame_samples, update
    from rgbd_envmap.geometry import look_at
    from rgbd_envmap.pipeline import PipelineConfig
    from rgbd_envmap.pipeline.capture import CaptureConfig
    from rgbd_envmap.sh import IncrementalProjection
    from rgbd_envmap.types import Intrinsics, RGBDFrame

    install_from_env()
    cfg = CaptureConfig()
    threads = PipelineConfig().threads
    rng = np.random.default_rng(0)
    intr = Intrinsics(16, 12, 14.0, 14.0, 7.5, 5.5)
    frames = []
    for step, target in enumerate(([1.0, 0.2, 0.0], [1.0, -0.3, 0.1])):
        T = look_at([0.01 * step, 0.0, 0.0], target)
        frames.append(RGBDFrame(rng.random((12, 16, 3)).astype(np.float32),
                                rng.uniform(1.0, 2.0, (12, 16)).astype(np.float32), np.ones((12, 16), bool), T, intr, step))
    # 1. Rendering and compositing a colour frame: the object and shadow plane of the default
    # config in front of a 64×48 camera (arrays as the pipeline passes them).
    oc = PipelineConfig().object
    obj = assets.load_virtual_object(oc.name, height_m=oc.height_m)
    plane_v, plane_f = prt.plane_grid(oc.plane_size_m, oc.plane_resolution)
    base = np.array([1.0, 0.0, -0.2])
    cam = Intrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)
    renderer = render.Renderer(cam, backend="numba")
    try:
        layer = renderer.render(look_at([0.0, 0.0, 0.0], base), obj.vertices + base, obj.faces,
                                np.full((len(obj.vertices), 3), 0.5, np.float32), plane_v + base, plane_f,
                                np.full(len(plane_v), 0.5, np.float32))
        render.composite(np.zeros((48, 64, 3), np.uint8), layer, ccm_inverse=np.eye(3), shadow_grey=0.15)
    finally:
        renderer.close()
    # 1b. The differential composite (the default): its composite, the receivers' shading and
    # occlusion and the lights, through the functions the pipeline calls.
    _differential(np, obj, base, threads)
    # 2. Colour pairs and the fit (a map with data everywhere: depth 1.5 m).
    em = EnvironmentMap(20, 40)
    em.valid[:] = True
    em.depth_m[:] = 1.5
    em.radiance_planes[:] = rng.random(em.radiance_planes.shape, dtype=np.float32)
    f = frames[0]
    # A writable mask, as mark_reliable's (frames hold read-only arrays: numba compiles another
    # specialisation for those).
    *sums, _ = frame_pair_sums(em, f.depth_m, f.known.copy(), intr, f.T_world_from_cam, f.rgb,
                               cfg.pair_max_depth_diff_m, threads=threads)
    ccm_from_sums(*sums, cfg.ccm_method, max_mse=cfg.max_mse, min_pairs=1, max_condition=DEFAULT_MAX_CONDITION,
                   noise_std=None, ridge=DEFAULT_RIDGE)
    # 3. The SH projection, then the tracker on changes logged as the update logs them (raster
    # order; new data and changed colours), without the update.
    em.valid[:, ::3] = False
    tracker = IncrementalProjection(5)
    tracker.coefficients(em)  # the first call projects the whole map and starts the log
    log = em.change_log
    idx = np.arange(0, em.height * em.width, 7, dtype=np.int64)
    log.idx[:len(idx)] = idx
    log.old[:len(idx)] = em.radiance_planes.reshape(3, -1)[:, idx].T
    log.was_valid[:len(idx)] = em.valid.reshape(-1)[idx]
    log.n, log.updates = len(idx), 1
    em.valid.reshape(-1)[idx] = True
    em.radiance_planes.reshape(3, -1)[:, idx] = 0.5
    tracker.coefficients(em)
    # 4. The samples and the map update (with the change log, as the capture runs it).
    em = EnvironmentMap(20, 40)
    em.record_changes()
    for frame in frames:
        T = frame.T_world_from_cam
        flags = np.zeros((12, 16), np.uint8)  # the edge margin's dilated mask
        pts, colours, fill_only = frame_samples(frame.depth_m, frame.known, intr, T, frame.rgb, flags, np.eye(3))
        update(em, pts, colours, T.translation, 14.0, cfg.update, fill_only, SeenDepth(frame.depth_m, frame.known, intr, T),
               threads=threads)
    return 0


def _differential(np, obj, base, threads: int) -> None:
    """The differential composite's kernels on a 40×80 map with a lamp, a small support plane under
    the object as the receivers and a random transfer (the pipeline's dtypes and layouts)."""
    from rgbd_envmap import render
    from rgbd_envmap.envmap import EnvironmentMap
    from rgbd_envmap.geometry import look_at
    from rgbd_envmap.lights import AreaLightState, direct_part, light_grid, sample_lights
    from rgbd_envmap.pipeline import PipelineConfig
    from rgbd_envmap.render.differential import DifferentialShader
    from rgbd_envmap.render.geometry import surface_radiance, support_plane
    from rgbd_envmap.types import Intrinsics

    rc = PipelineConfig().render
    bands = PipelineConfig().shading.bands
    rng = np.random.default_rng(1)
    em = EnvironmentMap(40, 80, origin=base + np.array([0.0, 0.0, 0.05]))
    em.valid[:] = True
    em.depth_m[:] = 1.5
    em.radiance_planes[:] = rng.random(em.radiance_planes.shape, dtype=np.float32) * 0.3
    em.radiance_planes[:, :4] = 9.0  # a lamp near the zenith
    shader = DifferentialShader(obj.vertices.astype(np.float64) + base, obj.faces, obj.normals, samples=rc.occlusion_samples)
    mesh = support_plane(base, 0.1, 0.02)
    V = len(obj.vertices)
    transfer = rng.random((V, bands * bands), dtype=np.float32)
    colours = rng.random((V, 3), dtype=np.float32)
    coeffs = rng.random((bands * bands, 3))
    # the composite of a colour frame
    shader.set_receivers(mesh, bands, radiance=surface_radiance(em.radiance, em.valid, em.origin, mesh.vertices))
    _, ratio = shader.shade(None, coeffs, transfer, obj.albedo, object_colours=colours, object_coeffs=coeffs)
    cam = Intrinsics(64, 48, 60.0, 60.0, 31.5, 23.5)
    renderer = render.Renderer(cam, backend="numba")
    try:
        T = look_at([0.0, 0.0, 0.3], base)
        none = (np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros(0))
        layer = renderer.render(T, obj.vertices + base, obj.faces, colours, *none)
        receivers = renderer.render(T, mesh.vertices, shader.active_faces(ratio), ratio, *none)
        render.composite_differential(np.zeros((48, 64, 3), np.uint8), layer, receivers, ccm_inverse=np.eye(3),
                                      shadow_grey=rc.shadow_grey)
    finally:
        renderer.close()
    # the lights, then the receivers shaded by them
    k = rc.light_grid_stride
    sub = (slice(k // 2, None, k), slice(k // 2, None, k))
    radiance = light_grid(em.radiance, k)
    direct, _, _ = direct_part(radiance, rc.tau, bands, valid=np.ascontiguousarray(em.valid[sub]))
    options = {"points": rc.light_points, "state": AreaLightState()} if rc.light_method == "val" else {}
    lights = sample_lights(radiance, rc.lights, rc.light_method, valid=direct, depth_m=np.ascontiguousarray(em.depth_m[sub]),
                           origin=em.origin, **options)
    ratio = shader.shade(lights, coeffs, transfer, obj.albedo, object_colours=colours, object_coeffs=coeffs)[1]
    shader.active_faces(ratio)


if __name__ == "__main__":
    raise SystemExit(main())
