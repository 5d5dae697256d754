"""Tango ingest against independent references: OpenCV projection and remap, and simulator truth."""

import cv2
import numpy as np
import pytest

from rgbd_envmap.colour import srgb_to_linear
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError, ShapeError, UnknownMethodError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.ingest.tango import (
    TangoIngestConfig,
    colour_at_points,
    colour_filled_pixels,
    colour_registration,
    decode_colour,
    depth_image_from_points,
    rgbd_frame_from_packets,
)
from rgbd_envmap.types import ColourPacket, DepthPacket, Distortion, Intrinsics, RigidTransform
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.raycast import SceneRaycaster
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory

COLOUR_TOL = 1e-5  # float32 bilinear vs OpenCV's remap on float64 input
TOF = Intrinsics(64, 48, 50.0, 52.0, 31.5, 23.5, Distortion.radial(-0.05, 0.01, 0.0))
CAM = Intrinsics(80, 60, 70.0, 70.0, 39.5, 29.5, Distortion(0.05, -0.1, 0.001, -0.002, 0.02))


def _random_points(rng, n):
    xy = rng.uniform(-0.5, 0.5, (n, 2))
    z = rng.uniform(0.5, 3.0, n)
    return np.column_stack([xy * z[:, None], z]).astype(np.float32)


def test_depth_image_matches_opencv_projection_and_closest_wins():
    rng = np.random.default_rng(0)
    pts = _random_points(rng, 4000)
    conf = np.ones(len(pts), np.float32)
    img = depth_image_from_points(pts, conf, TOF)
    ref, _ = cv2.projectPoints(pts.astype(np.float64), np.zeros(3), np.zeros(3), TOF.K, TOF.distortion.coefficients)
    col, row = np.floor(ref[:, 0, 0] + 0.5).astype(int), np.floor(ref[:, 0, 1] + 0.5).astype(int)
    inside = (col >= 0) & (col < TOF.width) & (row >= 0) & (row < TOF.height)
    expected = np.full(TOF.shape, np.inf)
    np.minimum.at(expected, (row[inside], col[inside]), pts[inside, 2].astype(np.float64))
    np.testing.assert_array_equal(img.known, np.isfinite(expected))
    assert img.known.sum() > 1000
    np.testing.assert_allclose(img.depth_m[img.known], expected[img.known], rtol=1e-7)
    winners = img.point_index[img.known]
    np.testing.assert_array_equal(pts[winners, 2], img.depth_m[img.known])
    assert np.all(img.depth_m[~img.known] == 0) and np.all(img.point_index[~img.known] == -1)


def test_low_confidence_points_do_not_compete():
    pts = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.5]], np.float32)  # same pixel, the closer one is unsure
    img = depth_image_from_points(pts, np.array([0.9, 0.3], np.float32), TOF)
    assert img.known.sum() == 1 and img.depth_m[img.known][0] == 1.0
    img = depth_image_from_points(pts, np.array([0.69, 0.3], np.float32), TOF)
    assert not img.known.any()


def test_bad_points_are_dropped_not_fatal():
    pts = np.array([[np.nan, 0, 1], [0, np.inf, 1], [0, 0, -1.0], [0, 0, 0.0], [100.0, 0, 1.0], [0, 0, 2.0]], np.float32)
    conf = np.array([1, 1, 1, 1, 1, np.nan], np.float32)
    img = depth_image_from_points(pts, conf, TOF)
    assert not img.known.any()
    empty = depth_image_from_points(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), TOF)
    assert not empty.known.any() and empty.depth_m.shape == TOF.shape


def test_input_errors_are_typed():
    with pytest.raises(ShapeError):
        depth_image_from_points(np.zeros((5, 2)), np.ones(5), TOF)
    with pytest.raises(ShapeError):
        depth_image_from_points(np.zeros((5, 3)), np.ones(4), TOF)
    with pytest.raises(DTypeError):
        depth_image_from_points(np.zeros((5, 3), np.int32), np.ones(5), TOF)
    with pytest.raises(RangeError):
        DepthPacket(0, np.zeros((1, 3)), np.array([1.5]), RigidTransform.identity())
    with pytest.raises(InvalidInputError):
        ColourPacket(0, np.zeros((10, 8), np.uint8), RigidTransform.identity())  # 10 rows is not H·3/2
    with pytest.raises(UnknownMethodError):
        TangoIngestConfig(registration="magic")
    with pytest.raises(InvalidInputError):
        TangoIngestConfig(confidence_threshold=1.5)


def test_colour_matches_opencv_remap_of_the_linearised_image():
    rng = np.random.default_rng(1)
    srgb8 = rng.integers(0, 256, (CAM.height, CAM.width, 3), dtype=np.uint8)
    pts = _random_points(rng, 500)
    T = RigidTransform.from_rt(np.eye(3), np.array([0.02, -0.01, 0.0]), "colour", "depth")
    rgb, ok = colour_at_points(pts, srgb8, T, CAM)
    ref_uv, _ = cv2.projectPoints(T.apply(pts.astype(np.float64)), np.zeros(3), np.zeros(3), CAM.K, CAM.distortion.coefficients)
    ref_uv = ref_uv[:, 0]
    inside = (ref_uv[:, 0] >= 0) & (ref_uv[:, 0] <= CAM.width - 1) & (ref_uv[:, 1] >= 0) & (ref_uv[:, 1] <= CAM.height - 1)
    np.testing.assert_array_equal(ok, inside)
    lin = srgb_to_linear(srgb8.astype(np.float64) / 255.0).astype(np.float32)
    maps = ref_uv[inside].astype(np.float32).reshape(-1, 1, 2)
    ref = cv2.remap(lin, maps, None, cv2.INTER_LINEAR).reshape(-1, 3)
    np.testing.assert_allclose(rgb[ok], ref, atol=2e-3)  # remap uses 5-bit fixed-point weights
    # and exactly against a float64 bilinear written here
    u, v = ref_uv[inside, 0], ref_uv[inside, 1]
    u0 = np.minimum(np.floor(u).astype(int), CAM.width - 2)
    v0 = np.minimum(np.floor(v).astype(int), CAM.height - 2)
    au, av = (u - u0)[:, None], (v - v0)[:, None]
    exact = (1 - av) * ((1 - au) * lin[v0, u0] + au * lin[v0, u0 + 1]) + av * ((1 - au) * lin[v0 + 1, u0] + au * lin[v0 + 1, u0 + 1])
    np.testing.assert_allclose(rgb[ok], exact, atol=COLOUR_TOL)
    assert np.all(rgb[~ok] == 0)


def test_points_behind_the_colour_camera_get_no_colour():
    srgb8 = np.full((CAM.height, CAM.width, 3), 200, np.uint8)
    T = RigidTransform.from_rt(np.diag([1.0, -1.0, -1.0]), np.zeros(3))  # colour camera faces the other way
    _, ok = colour_at_points(np.array([[0.0, 0.0, 1.0]], np.float32), srgb8, T, CAM)
    assert not ok.any()


@pytest.fixture(scope="module")
def sim_frame():
    colour = ColourCameraConfig(width=320, height=240, shot_noise=0.0, read_noise=0.0)
    sim = Simulator(load_scene("office"), load_trajectory("orbit"), TangoDeviceConfig(colour=colour), seed=2)
    stream = sim.run(0.04)
    depth_sp, colour_sp = next(stream), next(stream)
    assert depth_sp.packet.timestamp_ns == colour_sp.packet.timestamp_ns
    srgb8 = decode_colour(colour_sp.packet)
    frame, image = rgbd_frame_from_packets(depth_sp.packet, srgb8, colour_sp.packet.T_world_from_colour, sim.calibration)
    return sim, depth_sp, colour_sp, srgb8, frame, image


def test_frame_depth_within_the_noise_model(sim_frame):
    sim, depth_sp, _, _, frame, _ = sim_frame
    true = depth_sp.groundtruth["true_depth_m"]
    clean = frame.known & (depth_sp.groundtruth["flags"] == 0) & ~depth_sp.groundtruth["mixed"]
    rel = np.abs(frame.depth_m[clean] - true[clean]) / true[clean]
    assert frame.known.mean() > 0.7
    assert np.median(rel) < sim.device.tof.noise_rel  # median |N(0, σ)| = 0.67 σ


def test_frame_colour_equals_true_radiance_times_gains(sim_frame):
    sim, depth_sp, colour_sp, _, frame, _ = sim_frame
    obj = depth_sp.groundtruth["object_index"]
    pad = np.pad(obj, 2, mode="edge")
    uniform = np.ones(obj.shape, bool)
    for dy in range(5):
        for dx in range(5):
            uniform &= pad[dy:dy + obj.shape[0], dx:dx + obj.shape[1]] == obj
    sel = frame.known & uniform & (depth_sp.groundtruth["flags"] == 0)
    # Truth: radiance where each pixel's point actually is, seen by the colour camera with its gains.
    T = depth_sp.packet.T_world_from_depth
    pts = frame.depth_m[sel, None] * pixel_rays(frame.intrinsics)[sel]
    dirs = T.rotate(pts / np.linalg.norm(pts, axis=1, keepdims=True))
    radiance = SceneRaycaster(sim.scene).cast(T.translation, dirs, 0.0).radiance
    expected = np.clip(radiance * colour_sp.groundtruth["gains"], 0, 1)
    err = np.abs(frame.rgb[sel] - expected)
    assert sel.sum() > 5000
    assert np.median(err) < 0.01 and np.percentile(err, 95) < 0.05


def test_registration_from_poses_equals_extrinsics_when_simultaneous(sim_frame):
    sim, depth_sp, colour_sp, _, _, _ = sim_frame
    a = colour_registration(depth_sp.packet, colour_sp.packet.T_world_from_colour, sim.calibration, "poses")
    b = colour_registration(depth_sp.packet, colour_sp.packet.T_world_from_colour, sim.calibration, "extrinsics")
    np.testing.assert_allclose(a.matrix, b.matrix, atol=1e-9)


def test_filled_pixels_take_colour_from_their_3d_point(sim_frame):
    sim, depth_sp, colour_sp, srgb8, frame, _ = sim_frame
    # "Fill" every in-range pixel with its true depth: the new pixels' colour must be what the colour
    # camera sees there, and known pixels must not change.
    true, valid = depth_sp.groundtruth["true_depth_m"], depth_sp.groundtruth["true_valid"]
    T_cd = colour_registration(depth_sp.packet, colour_sp.packet.T_world_from_colour, sim.calibration)
    filled = colour_filled_pixels(frame, np.where(frame.known, frame.depth_m, true), frame.known | valid, srgb8, T_cd, sim.calibration.colour)
    np.testing.assert_array_equal(filled.rgb[frame.known], frame.rgb[frame.known])
    np.testing.assert_array_equal(filled.depth_m[frame.known], frame.depth_m[frame.known])
    new = filled.known & ~frame.known
    assert new.sum() > 100 and np.all(filled.rgb[new].sum(axis=1) > 0)
    assert filled.known.sum() > 0.99 * (frame.known | valid).sum()  # the colour camera sees nearly all


def test_wrong_colour_image_size_is_an_error(sim_frame):
    sim, depth_sp, colour_sp, srgb8, _, _ = sim_frame
    with pytest.raises(ShapeError):
        rgbd_frame_from_packets(depth_sp.packet, srgb8[:-2], colour_sp.packet.T_world_from_colour, sim.calibration)
