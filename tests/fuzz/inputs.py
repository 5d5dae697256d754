"""Valid inputs for every public function the fuzz table calls, and the bad inputs made from them.

``CALLS[name]`` is ``(function, good)``: ``good()`` returns fresh keyword arguments for a call that
succeeds; the table replaces one argument with a bad input (``MUTATORS``) and states what must happen.
Everything is small (images of 12×16 pixels, maps of 8×16) so that the whole table runs in seconds.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rgbd_envmap import colour, config, envmap, envmap_io, geometry, metrics, prt, sh
from rgbd_envmap.depth import denoise, holes, reliability
from rgbd_envmap.envmap import EnvironmentMap, UpdateConfig
from rgbd_envmap.ingest import kinect, tango
from rgbd_envmap.ingest.tango import TangoIngestConfig
from rgbd_envmap.render import Layer, Renderer, composite
from rgbd_envmap.sh import bands as sh_bands
from rgbd_envmap.sh import projection as sh_projection
from rgbd_envmap.types import (
    Calibration, ColourPacket, DepthPacket, Distortion, Intrinsics, RGBDFrame, RigidTransform,
)

H, W = 12, 16                 # depth image
CH, CW = 12, 16               # colour image
MH, MW = 8, 16                # environment map
INTR = Intrinsics(W, H, 14.0, 14.0, 7.5, 5.5, Distortion.radial(-0.02, 0.0, 0.0))
CINTR = Intrinsics(CW, CH, 14.0, 14.0, 7.5, 5.5)
T_WD = RigidTransform.identity("world", "depth")
T_WC = RigidTransform.identity("world", "colour")
T_CD = RigidTransform.identity("colour", "depth")
CAL = Calibration("tango", INTR, CINTR, T_CD)


def _rng():
    return np.random.default_rng(7)


def depth_image():
    rng = _rng()
    return (1.5 + 0.01 * rng.standard_normal((H, W))).astype(np.float32)


def known_image():
    k = np.ones((H, W), bool)
    k[4:6, 5:8] = False
    return k


def rgb_image():
    return _rng().uniform(0.2, 0.8, (H, W, 3)).astype(np.float32)


def srgb8_image():
    return _rng().integers(0, 256, (CH, CW, 3), dtype=np.uint8)


def points_cam(n=60):
    rng = _rng()
    p = np.stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.3, 0.3, n), rng.uniform(1.0, 2.0, n)], axis=1)
    return p.astype(np.float32)


def confidence(n=60):
    return np.full(n, 0.9, np.float32)


def nv21_buffer():
    return colour.encode_nv21(srgb8_image())


def depth_packet():
    return DepthPacket(1, points_cam(), confidence(), T_WD)


def colour_packet():
    return ColourPacket(1, nv21_buffer(), T_WC)


def frame():
    return RGBDFrame(rgb_image(), depth_image(), known_image(), T_WD, INTR, 1)


def map_full():
    rng = _rng()
    rad = rng.uniform(0.1, 0.9, (MH, MW, 3)).astype(np.float32)
    return EnvironmentMap.from_arrays(rad, np.full((MH, MW), 2.0, np.float32), np.ones((MH, MW), bool), np.zeros(3))


def world_points(n=60):
    rng = _rng()
    d = rng.standard_normal((n, 3))
    return (2.0 * d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


def colours(n=60):
    return _rng().uniform(0.1, 0.9, (n, 3)).astype(np.float32)


def equirect_image(c=3):
    return _rng().uniform(0.1, 0.9, (MH, MW, c) if c else (MH, MW)).astype(np.float32)


def unit_dirs(n=20):
    d = _rng().standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sh_coeffs(bands=3):
    c = np.zeros((bands * bands, 3))
    c[0] = 1.0
    c[1:4] = 0.1
    return c


def tet():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * 0.1
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int32)
    n = v - v.mean(0)
    return v, f, n / np.linalg.norm(n, axis=1, keepdims=True)


def transfer(bands=3, n=5):
    return np.abs(_rng().standard_normal((n, bands * bands))).astype(np.float32)


def layer():
    lay = Layer.empty(CH, CW)
    return lay


def ccm_pairs(n=600):
    rng = _rng()
    src = rng.uniform(0.1, 0.9, (n, 3))
    m = np.array([[1.1, 0.05, 0.0], [0.02, 0.9, 0.03], [0.0, 0.04, 1.05]])
    return src, src @ m.T


def seen():
    return envmap.SeenDepth(depth_image(), known_image(), INTR, T_WD)


def _hdr_file(tmp="/tmp/fuzz_envmap.hdr"):
    envmap_io.write_hdr(tmp, equirect_image(), np.ones((MH, MW), bool))
    return tmp


def _kinect_merger():
    return kinect.KinectMerger(INTR)


def _merger_step(merger, **kw):
    return merger.step(**kw)


def _renderer_render(renderer, **kw):
    return renderer.render(**kw)


def _frame_with_depth(frame, depth_m):
    return frame.with_depth(depth_m)


def _compose(a, b):
    return a @ b


def _apply(T, points):
    return T.apply(points)


def _rotate(T, vectors):
    return T.rotate(vectors)


def _scaled(intrinsics, width, height):
    return intrinsics.scaled(width, height)


def _changes_roundtrip(capacity):
    return envmap.ChangeLog(capacity)


def _incremental(projection, em):
    return projection.coefficients(em)


def _plane():
    v, f, n = tet()
    from rgbd_envmap.assets import object_from_mesh
    return object_from_mesh(v, f)


def _map_arrays(em):
    """What a call that changes a map gives: the map's valid radiance and distance (checked for NaN)."""
    return em.radiance[em.valid], em.depth_m[em.valid], em.valid


def _update(em, **kw):
    stats = envmap.update(em, **kw)
    return stats, *_map_arrays(em)


def _translate(**kw):
    return _map_arrays(envmap.translate(**kw))


def _new_map(cls_call, **kw):
    return _map_arrays(cls_call(**kw))


def _renderer():
    return Renderer(CINTR)


# name → (function, good keyword arguments)
CALLS = {
    # types
    "Distortion": (Distortion, lambda: dict(k1=0.1, k2=0.0, p1=0.0, p2=0.0, k3=0.0)),
    "Intrinsics": (Intrinsics, lambda: dict(width=16, height=12, fx=14.0, fy=14.0, cx=7.5, cy=5.5)),
    "Intrinsics.scaled": (_scaled, lambda: dict(intrinsics=INTR, width=32, height=24)),
    "Intrinsics.from_dict": (Intrinsics.from_dict, lambda: dict(d=INTR.to_dict())),
    "RigidTransform": (RigidTransform, lambda: dict(matrix=np.eye(4), dst="world", src="depth")),
    "RigidTransform.from_rt": (RigidTransform.from_rt, lambda: dict(rotation=np.eye(3), translation=np.zeros(3))),
    "RigidTransform.from_quaternion": (RigidTransform.from_quaternion,
                                       lambda: dict(translation=np.zeros(3), quat_xyzw=np.array([0, 0, 0, 1.0]))),
    "RigidTransform.apply": (_apply, lambda: dict(T=T_WD, points=points_cam())),
    "RigidTransform.rotate": (_rotate, lambda: dict(T=T_WD, vectors=unit_dirs())),
    "RigidTransform @": (_compose, lambda: dict(a=T_WC, b=T_CD)),
    "DepthPacket": (DepthPacket, lambda: dict(timestamp_ns=1, points_m=points_cam(), confidence=confidence(),
                                              T_world_from_depth=T_WD)),
    "ColourPacket": (ColourPacket, lambda: dict(timestamp_ns=1, nv21=nv21_buffer(), T_world_from_colour=T_WC)),
    "Calibration": (Calibration, lambda: dict(sensor="tango", depth=INTR, colour=CINTR, T_colour_from_depth=T_CD)),
    "Calibration.from_dict": (Calibration.from_dict, lambda: dict(d=CAL.to_dict())),
    "RGBDFrame": (RGBDFrame, lambda: dict(rgb=rgb_image(), depth_m=depth_image(), known=known_image(),
                                          T_world_from_cam=T_WD, intrinsics=INTR, timestamp_ns=1)),
    "RGBDFrame.with_depth": (_frame_with_depth, lambda: dict(frame=frame(), depth_m=depth_image())),
    # config
    "config.to_dict": (config.to_dict, lambda: dict(cfg=UpdateConfig())),
    "config.from_dict": (config.from_dict, lambda: dict(cls=UpdateConfig, data={"carve": False})),
    "config.apply_overrides": (config.apply_overrides, lambda: dict(cfg=UpdateConfig(), overrides=["carve=false"])),
    "config.dump_yaml": (config.dump_yaml, lambda: dict(cfg=UpdateConfig(), path="/tmp/fuzz_cfg.yaml")),
    # metrics
    "ws_psnr": (metrics.ws_psnr, lambda: dict(a=equirect_image(), b=equirect_image() * 0.9, valid=None, peak=1.0)),
    "sphere_correlation": (metrics.sphere_correlation, lambda: dict(a=equirect_image(), b=equirect_image() ** 2)),
    "coverage": (metrics.coverage, lambda: dict(valid=np.ones((MH, MW), bool))),
    "coverage_of": (metrics.coverage_of, lambda: dict(valid=np.ones((MH, MW), bool), reference_valid=np.ones((MH, MW), bool))),
    "data_loss": (metrics.data_loss, lambda: dict(before_valid=np.ones((MH, MW), bool), after_valid=np.ones((MH, MW), bool))),
    "depth_errors": (metrics.depth_errors, lambda: dict(estimate=np.full((MH, MW), 2.0), truth=np.full((MH, MW), 2.1),
                                                        mask=np.ones((MH, MW), bool))),
    "composite_errors": (metrics.composite_errors, lambda: dict(
        ours=np.full((12, 16, 3), 0.5), with_object=np.full((12, 16, 3), 0.55), without_object=np.full((12, 16, 3), 0.6),
        object_mask=np.pad(np.ones((4, 4), bool), ((2, 6), (2, 10))), valid=np.ones((12, 16), bool),
        shadow_threshold=0.02, window_px=3)),
    # geometry
    "distort_normalized": (geometry.distort_normalized, lambda: dict(xy=np.full((5, 2), 0.1), distortion=INTR.distortion)),
    "undistort_normalized": (geometry.undistort_normalized, lambda: dict(xy_distorted=np.full((5, 2), 0.1),
                                                                       distortion=INTR.distortion, iterations=20)),
    "project_points": (geometry.project_points, lambda: dict(points_cam=points_cam(), intrinsics=INTR)),
    "unproject_pixels": (geometry.unproject_pixels, lambda: dict(uv=np.full((5, 2), 3.0), depth_m=np.full(5, 1.5), intrinsics=INTR)),
    "pixel_rays": (geometry.pixel_rays, lambda: dict(intrinsics=INTR)),
    "look_at": (geometry.look_at, lambda: dict(eye=np.zeros(3), target=np.array([1.0, 0, 0]), up=np.array([0, 0, 1.0]))),
    "opengl_from_opencv": (geometry.opengl_from_opencv, lambda: dict(T_world_from_cam=T_WC)),
    "equirect_directions": (geometry.equirect_directions, lambda: dict(height=MH, width=MW)),
    "equirect_solid_angles": (geometry.equirect_solid_angles, lambda: dict(height=MH, width=MW)),
    "directions_to_equirect": (geometry.directions_to_equirect, lambda: dict(dirs=unit_dirs(), height=MH, width=MW)),
    "equirect_to_directions": (geometry.equirect_to_directions, lambda: dict(uv=np.full((5, 2), 3.0), height=MH, width=MW)),
    "equirect_pixel_index": (geometry.equirect_pixel_index, lambda: dict(dirs=unit_dirs(), height=MH, width=MW)),
    # envmap_io
    "to_convention": (envmap_io.to_convention, lambda: dict(image=equirect_image(), convention="blender")),
    "from_convention": (envmap_io.from_convention, lambda: dict(image=equirect_image(), convention="mitsuba")),
    "write_hdr": (envmap_io.write_hdr, lambda: dict(path="/tmp/fuzz_w.hdr", radiance=equirect_image(), valid=None)),
    "write_exr": (envmap_io.write_exr, lambda: dict(path="/tmp/fuzz_w.exr", radiance=equirect_image(), valid=None, depth_m=None)),
    "write_envmap": (envmap_io.write_envmap, lambda: dict(path="/tmp/fuzz_w2.hdr", radiance=equirect_image(),
                                                          valid=np.ones((MH, MW), bool))),
    "read_envmap": (envmap_io.read_envmap, lambda: dict(path=_hdr_file(), convention=None)),
    "read_hdr": (envmap_io.read_hdr, lambda: dict(path=_hdr_file())),
    "format_of": (envmap_io.format_of, lambda: dict(path="x.hdr")),
    # prt
    "compute_transfer": (prt.compute_transfer, lambda: dict(vertices=tet()[0], normals=tet()[2], faces=tet()[1], bands=3, n_dirs=64)),
    "unoccluded_transfer": (prt.unoccluded_transfer, lambda: dict(normals=unit_dirs(), bands=3)),
    "sphere_directions": (prt.sphere_directions, lambda: dict(n_dirs=64, seed=0)),
    "plane_grid": (prt.plane_grid, lambda: dict(size_m=0.5, resolution=4)),
    "shade": (prt.shade, lambda: dict(transfer=transfer(), coeffs=sh_coeffs(), albedo=0.5, out=np.zeros((5, 3), np.float32))),
    # colour
    "decode_nv21": (colour.decode_nv21, lambda: dict(nv21=nv21_buffer(), height=CH, width=CW)),
    "encode_nv21": (colour.encode_nv21, lambda: dict(rgb=srgb8_image())),
    "srgb_to_linear": (colour.srgb_to_linear, lambda: dict(rgb=rgb_image())),
    "linear_to_srgb": (colour.linear_to_srgb, lambda: dict(rgb=rgb_image())),
    "estimate_ccm": (colour.estimate_ccm, lambda: dict(src=ccm_pairs()[0], dst=ccm_pairs()[1], method="least_squares",
                                                       max_mse=0.05, min_pairs=500, ridge=0.1, max_condition=1e4)),
    "ccm_sums": (colour.ccm_sums, lambda: dict(src=ccm_pairs()[0], dst=ccm_pairs()[1], saturation=1.0)),
    "apply_ccm": (colour.apply_ccm, lambda: dict(rgb=rgb_image(), matrix=np.eye(3))),
    "invert_ccm": (colour.invert_ccm, lambda: dict(matrix=np.eye(3) * 1.1)),
    # depth
    "denoise_depth": (denoise.denoise_depth, lambda: dict(depth_m=depth_image(), known=known_image(), intrinsics=INTR)),
    "denoise_frame": (denoise.denoise_frame, lambda: dict(frame=frame())),
    "fill_holes": (holes.fill_holes, lambda: dict(depth_m=depth_image(), known=known_image(), method="monroy2018")),
    "fill_holes_flagged": (holes.fill_holes_flagged, lambda: dict(depth_m=depth_image(), known=known_image(), max_source_ratio=1.5)),
    "exposure_ok": (reliability.exposure_ok, lambda: dict(rgb=rgb_image())),
    "discontinuity_test": (reliability.discontinuity_test, lambda: dict(depth_m=depth_image(), known=known_image())),
    "discontinuity_passed": (reliability.discontinuity_passed, lambda: dict(depth_m=depth_image(), known=known_image())),
    "mark_reliable": (reliability.mark_reliable, lambda: dict(rgb=rgb_image(), depth_m=depth_image(), known=known_image())),
    # envmap
    "EnvironmentMap": (lambda **kw: _new_map(EnvironmentMap, **kw), lambda: dict(height=MH, width=MW, origin=np.zeros(3))),
    "EnvironmentMap.from_arrays": (lambda **kw: _new_map(EnvironmentMap.from_arrays, **kw), lambda: dict(
        radiance=equirect_image(), depth_m=np.full((MH, MW), 2.0, np.float32), valid=np.ones((MH, MW), bool), origin=np.zeros(3))),
    "ChangeLog": (_changes_roundtrip, lambda: dict(capacity=1000)),
    "check_map": (envmap.check_map, lambda: dict(em=map_full())),
    "SeenDepth": (envmap.SeenDepth, lambda: dict(depth_m=depth_image(), known=known_image(), intrinsics=INTR, T_world_from_cam=T_WD)),
    "update": (_update, lambda: dict(em=EnvironmentMap(MH, MW), points_world=world_points(), colours=colours(),
                                           device_position=np.zeros(3), focal_px=14.0, config=UpdateConfig(),
                                           fill_only=None, seen=seen())),
    "map_coordinates": (envmap.map_update.map_coordinates, lambda: dict(points_world=world_points(), origin=np.zeros(3), height=MH, width=MW)),
    "collect_pairs": (envmap.collect_pairs, lambda: dict(em=map_full(), points_world=world_points(), colours=colours())),
    "frame_points": (envmap.frame_points, lambda: dict(depth_m=depth_image(), mask=known_image(), intrinsics=INTR, T_world_from_cam=T_WD)),
    "frame_pairs": (envmap.frame_pairs, lambda: dict(em=map_full(), depth_m=depth_image(), mask=known_image(), intrinsics=INTR,
                                                     T_world_from_cam=T_WD, rgb=rgb_image())),
    "frame_pair_sums": (envmap.frame_pair_sums, lambda: dict(em=map_full(), depth_m=depth_image(), mask=known_image(), intrinsics=INTR,
                                                             T_world_from_cam=T_WD, rgb=rgb_image())),
    "frame_samples": (envmap.frame_samples, lambda: dict(depth_m=depth_image(), mask=known_image(), intrinsics=INTR,
                                                         T_world_from_cam=T_WD, rgb=rgb_image())),
    "translate": (_translate, lambda: dict(em=map_full(), offset=np.array([0.1, 0.0, 0.0]), method="depth", radius_m=2.0,
                                           max_splat_px=8, max_rel_jump=0.2, out=EnvironmentMap(MH, MW), threads=2)),
    "reprojected_coordinates": (envmap.translation.reprojected_coordinates, lambda: dict(em=map_full(), offset=np.array([0.1, 0, 0]))),
    # ingest
    "KinectMergeConfig": (kinect.KinectMergeConfig, lambda: dataclasses.asdict(kinect.KinectMergeConfig())),
    "KinectMerger": (kinect.KinectMerger, lambda: dict(intrinsics=INTR)),
    "KinectMerger.step": (_merger_step, lambda: dict(merger=_kinect_merger(), depth_m=depth_image(), known=known_image(),
                                                    T_world_from_cam=T_WC)),
    "warp_depth": (kinect.warp_depth, lambda: dict(depth_m=depth_image(), weight=np.ones((H, W), np.float32), known=known_image(),
                                                   intrinsics=INTR, T_cur_from_prev=RigidTransform.identity())),
    "merge_depth": (kinect.merge_depth, lambda: dict(warped_depth=depth_image(), warped_weight=np.ones((H, W), np.float32),
                                                     warped_known=known_image(), new_depth=depth_image(), new_known=known_image())),
    "normals_from_depth": (kinect.normals_from_depth, lambda: dict(depth_m=depth_image(), known=known_image(), intrinsics=INTR)),
    "kinect_rgbd_frame": (kinect.kinect_rgbd_frame, lambda: dict(merged_depth=depth_image(), known=known_image(),
                                                                 rgb_uint8=srgb8_image(), T_world_from_cam=T_WC, intrinsics=INTR,
                                                                 timestamp_ns=1)),
    "TangoIngestConfig": (TangoIngestConfig, lambda: dataclasses.asdict(TangoIngestConfig())),
    "depth_image_from_points": (tango.depth_image_from_points, lambda: dict(points_m=points_cam(), confidence=confidence(), intrinsics=INTR)),
    "colour_at_points": (tango.colour_at_points, lambda: dict(points_m=points_cam(), srgb8=srgb8_image(), T_colour_from_depth=T_CD,
                                                              colour_intrinsics=CINTR)),
    "decode_colour": (tango.decode_colour, lambda: dict(packet=colour_packet())),
    "colour_registration": (tango.colour_registration, lambda: dict(depth_packet=depth_packet(), T_world_from_colour=T_WC, calibration=CAL)),
    "rgbd_frame_from_packets": (tango.rgbd_frame_from_packets, lambda: dict(depth_packet=depth_packet(), srgb8=srgb8_image(),
                                                                            T_world_from_colour=T_WC, calibration=CAL)),
    "ingest_tango": (tango.ingest_tango, lambda: dict(depth_packet=depth_packet(), srgb8=srgb8_image(), T_world_from_colour=T_WC,
                                                      calibration=CAL, config=TangoIngestConfig())),
    "colour_filled_pixels": (tango.colour_filled_pixels, lambda: dict(frame=frame(), filled_depth_m=depth_image(), filled_known=known_image(),
                                                                      srgb8=srgb8_image(), T_colour_from_depth=T_CD, colour_intrinsics=CINTR)),
    # render
    "Renderer": (Renderer, lambda: dict(intrinsics=CINTR)),
    "Renderer.render": (_renderer_render, lambda: dict(
        renderer=_renderer(), T_world_from_cam=RigidTransform(geometry.look_at(np.array([0, -1.0, 0.05]), np.zeros(3)).matrix, "world", "colour"),
        object_vertices_world=tet()[0], object_faces=tet()[1], object_colours=np.full((4, 3), 0.5, np.float32),
        plane_vertices_world=tet()[0], plane_faces=tet()[1], plane_alpha=np.full(4, 0.5, np.float32))),
    "composite": (composite, lambda: dict(frame_srgb=srgb8_image(), layer=layer())),
    "Layer.empty": (Layer.empty, lambda: dict(height=CH, width=CW)),
    # sh
    "sh.basis": (sh.basis, lambda: dict(dirs=unit_dirs(), bands=3)),
    "sh.irradiance": (sh.irradiance, lambda: dict(coeffs=sh_coeffs(), normals=unit_dirs())),
    "lambertian_band_factors": (sh.lambertian_band_factors, lambda: dict(bands=3)),
    "legendre": (sh.legendre, lambda: dict(z=np.linspace(-1, 1, 5), bands=3)),
    "n_bands": (sh.n_bands, lambda: dict(n_coeffs=9)),
    "check_bands": (sh.check_bands, lambda: dict(bands=3)),
    "project_equirect": (sh.project_equirect, lambda: dict(radiance=equirect_image(), valid=None, bands=3)),
    "project_planar": (sh.project_planar, lambda: dict(planes=np.ascontiguousarray(equirect_image().transpose(2, 0, 1)), bands=3)),
    "fill_missing": (sh.fill_missing, lambda: dict(radiance=equirect_image(), valid=known_image()[:MH, :MW], radius_px=5)),
    "fill_plan": (sh.fill_plan, lambda: dict(valid=known_image()[:MH, :MW], radius_px=5)),
    "projection_tables": (sh_projection.projection_tables, lambda: dict(height=MH, width=MW, bands=3)),
    "IncrementalProjection": (sh.IncrementalProjection, lambda: dict(bands=3, fill_radius_px=5)),
    "IncrementalProjection.coefficients": (_incremental, lambda: dict(projection=sh.IncrementalProjection(3), em=map_full())),
    "select_bands": (sh_bands.select_bands, lambda: dict(coeffs=np.tile(sh_coeffs(4), 1), transfer=transfer(4), tolerance=0.01)),
    "transfer_gram": (sh_bands.transfer_gram, lambda: dict(transfer=transfer(4))),
    "UpdateConfig": (UpdateConfig, lambda: dataclasses.asdict(UpdateConfig())),
}
