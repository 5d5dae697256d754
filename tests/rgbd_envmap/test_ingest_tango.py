"""Tango ingest against independent references: OpenCV projection and remap, and simulator truth."""

import dataclasses

import cv2
import numpy as np
import pytest

from rgbd_envmap.colour import srgb_to_linear
from rgbd_envmap.depth import fill_holes
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError, ShapeError, UnknownMethodError
from rgbd_envmap.geometry import pixel_rays
from rgbd_envmap.ingest import tango
from rgbd_envmap.ingest.tango import (
    TangoIngestConfig,
    colour_at_points,
    colour_filled_pixels,
    colour_registration,
    decode_colour,
    depth_image_from_points,
    ingest_tango,
    rgbd_frame_from_packets,
)
from rgbd_envmap.reference.tango import rgbd_frame_reference
from rgbd_envmap.types import Calibration, ColourPacket, DepthPacket, Distortion, Intrinsics, RGBDFrame, RigidTransform
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
    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit"), TangoDeviceConfig(colour=colour), seed=2)
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


# --- the SIMD passes against a per-point transcription ------------------------------------------------
#
# The kernels split the work into passes (projection of all points, z-buffer, bilinear lookups) so the
# arithmetic compiles to SIMD code. They promise the same IEEE sequence as one plain per-point loop;
# rgbd_envmap.reference.tango.rgbd_frame_reference is that loop, written out with numpy scalars
# (float32 where the kernels keep float32, float64 where they widen), and the results must agree bit
# for bit.

def _packet_with_awkward_points(rng, n=3000):
    pts = _random_points(rng, n)
    m = n // 5
    pts[rng.choice(n, m, replace=False)] = pts[rng.choice(n, m, replace=False)]  # shared pixels …
    pts[rng.choice(n, m // 2, replace=False), 2] *= np.float32(1.0 + 1e-3)  # … with near-ties
    bad = rng.choice(n, 60, replace=False)
    pts[bad[:15], 0] = np.nan
    pts[bad[15:30], 2] = -pts[bad[15:30], 2]
    pts[bad[30:45], 2] = 0.0
    pts[bad[45:], 1] = np.inf
    conf = rng.uniform(0.5, 1.0, n).astype(np.float32)
    conf[rng.choice(n, 20, replace=False)] = np.float32(0.7)  # 0.69999999: below the float64 threshold
    return pts, conf


def test_rgbd_frame_is_bit_identical_to_the_per_point_loop():
    cam = CAM
    rng = np.random.default_rng(21)
    pts, conf = _packet_with_awkward_points(rng)
    srgb8 = rng.integers(0, 256, (cam.height, cam.width, 3), dtype=np.uint8)
    T_wd = RigidTransform.from_rt(np.eye(3), np.zeros(3), "world", "depth")
    rot = RigidTransform.from_quaternion(np.array([0.03, -0.02, 0.01]), np.array([0.01, -0.02, 0.005, 1.0]))
    T_wc = RigidTransform(rot.matrix, "world", "colour")
    cal = Calibration("tango", TOF, cam, RigidTransform(np.linalg.inv(T_wc.matrix), "colour", "depth"))
    packet = DepthPacket(5, pts, conf, T_wd)
    frame, image = rgbd_frame_from_packets(packet, srgb8, T_wc, cal)
    m = np.linalg.inv(T_wc.matrix) @ T_wd.matrix
    depth, index, rgb, known = rgbd_frame_reference(pts, conf, 0.7, TOF, m[:3, :3], m[:3, 3], cam, srgb8)
    assert known.sum() > 500 and (image.known & ~known).sum() > 50  # coloured, and depth-only pixels
    np.testing.assert_array_equal(image.point_index, index)
    np.testing.assert_array_equal(image.depth_m.view(np.uint32), depth.view(np.uint32))
    np.testing.assert_array_equal(image.known, index >= 0)
    np.testing.assert_array_equal(frame.known, known)
    np.testing.assert_array_equal(frame.rgb.view(np.uint32), rgb.view(np.uint32))
    np.testing.assert_array_equal(frame.depth_m.view(np.uint32), np.where(known, depth, np.float32(0)).view(np.uint32))


def test_frames_are_read_only_and_equal_to_the_checked_constructor():
    rng = np.random.default_rng(4)
    pts, conf = _packet_with_awkward_points(rng, 1000)
    srgb8 = rng.integers(0, 256, (CAM.height, CAM.width, 3), dtype=np.uint8)
    T = RigidTransform.identity("world", "depth")
    cal = Calibration("tango", TOF, CAM, RigidTransform.identity("colour", "depth"))
    frame, _ = rgbd_frame_from_packets(DepthPacket(1, pts, conf, T), srgb8, RigidTransform.identity("world", "colour"), cal)
    rebuilt = RGBDFrame(frame.rgb, frame.depth_m, frame.known, frame.T_world_from_cam, frame.intrinsics, frame.timestamp_ns)
    assert frame == rebuilt and type(frame.timestamp_ns) is int
    assert {f.name for f in dataclasses.fields(RGBDFrame)} == set(tango._FRAME_FIELDS)
    for a in (frame.rgb, frame.depth_m, frame.known):
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a[0, 0] = 0
    filled = colour_filled_pixels(frame, frame.depth_m, frame.known, srgb8, RigidTransform.identity("colour", "depth"), CAM)
    assert filled == frame and not filled.rgb.flags.writeable and filled.rgb is not frame.rgb


def test_registration_is_reused_only_for_the_same_poses():
    rng = np.random.default_rng(5)
    pts, conf = _packet_with_awkward_points(rng, 200)
    cal = Calibration("tango", TOF, CAM, RigidTransform.identity("colour", "depth"))
    T_wd = RigidTransform.from_rt(np.eye(3), np.array([0.1, 0.2, 0.3]), "world", "depth")
    T_wc = RigidTransform.from_quaternion(np.array([0.0, 0.1, 0.0]), np.array([0.0, 0.1, 0.0, 1.0]), "world", "colour")
    packet = DepthPacket(1, pts, conf, T_wd)
    a = colour_registration(packet, T_wc, cal)
    assert colour_registration(packet, T_wc, cal) is a  # the same immutable poses: the same result
    np.testing.assert_array_equal(a.matrix, np.linalg.inv(T_wc.matrix) @ T_wd.matrix)
    assert (a.dst, a.src) == ("colour", "depth")
    T_wc2 = RigidTransform(T_wc.matrix.copy(), "world", "colour")  # equal values, another object
    b = colour_registration(packet, T_wc2, cal)
    assert b is not a and b == a
    moved = RigidTransform.from_rt(np.eye(3), np.array([0.0, 0.0, 1.0]), "world", "colour")
    np.testing.assert_array_equal(colour_registration(packet, moved, cal).matrix,
                                  np.linalg.inv(moved.matrix) @ T_wd.matrix)
    assert colour_registration(packet, moved, cal, "extrinsics") is cal.T_colour_from_depth


def test_filled_pixels_match_the_per_point_formula_and_keep_everything_else():
    rng = np.random.default_rng(6)
    srgb8 = rng.integers(0, 256, (CAM.height, CAM.width, 3), dtype=np.uint8)
    known = rng.random(TOF.shape) > 0.3
    rgb = rng.random(TOF.shape + (3,)).astype(np.float32)  # colour at unknown pixels too: kept as is
    depth = np.where(known, rng.uniform(0.5, 3.0, TOF.shape), 0).astype(np.float32)
    frame = RGBDFrame(rgb, depth, known, RigidTransform.identity(), TOF, 3)
    filled_depth = rng.uniform(0.5, 3.0, TOF.shape)  # float64: rounded once to float32 where taken
    filled_known = known | (rng.random(TOF.shape) > 0.4)
    T = RigidTransform.from_rt(np.eye(3), np.array([0.3, 0.0, 0.0]), "colour", "depth")  # some fall outside
    out = colour_filled_pixels(frame, filled_depth, filled_known, srgb8, T, CAM)
    new = filled_known & ~known
    points = pixel_rays(TOF)[new] * filled_depth[new, None]
    colours, seen = colour_at_points(points, srgb8, T, CAM)
    assert 0 < seen.sum() < new.sum()
    exp_rgb = rgb.copy()
    exp_rgb[new] = colours
    exp_known = known.copy()
    exp_known[new] = seen
    exp_depth = np.where(known, depth, np.where(exp_known, filled_depth, 0.0)).astype(np.float32)
    np.testing.assert_array_equal(out.rgb, exp_rgb)
    np.testing.assert_array_equal(out.known, exp_known)
    np.testing.assert_array_equal(out.depth_m.view(np.uint32), exp_depth.view(np.uint32))


@pytest.mark.parametrize("axis", [0, 1], ids=["one column", "one row"])
def test_one_pixel_wide_colour_image_interpolates_along_the_other_axis(axis):
    # Points on the plane x = 0 (or y = 0) project to u = cx = 0 exactly with radial distortion only,
    # so a 1-column image is sampled along v alone (the 2×2 collapses onto the column).
    rng = np.random.default_rng(8)
    n = 200
    cam = (Intrinsics(1, 60, 70.0, 70.0, 0.0, 29.5, Distortion.radial(0.05, -0.1, 0.02)) if axis == 0 else
           Intrinsics(80, 1, 70.0, 70.0, 39.5, 0.0, Distortion.radial(0.05, -0.1, 0.02)))
    pts = np.zeros((n, 3))
    pts[:, 2] = rng.uniform(0.5, 3.0, n)
    pts[:, 1 - axis] = rng.uniform(-0.8, 0.8, n) * pts[:, 2]
    srgb8 = rng.integers(0, 256, (cam.height, cam.width, 3), dtype=np.uint8)
    rgb, ok = colour_at_points(pts, srgb8, RigidTransform.identity(), cam)
    line = srgb_to_linear(srgb8.reshape(-1, 3).astype(np.float64) / 255.0)
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, cam.distortion.coefficients)
    t = uv[:, 0, 1 - axis]
    inside = (t >= 0) & (t <= len(line) - 1)
    np.testing.assert_array_equal(ok, inside)
    assert 20 < ok.sum() < n
    expected = np.stack([np.interp(t[inside], np.arange(len(line)), line[:, c]) for c in range(3)], axis=1)
    np.testing.assert_allclose(rgb[ok], expected, atol=COLOUR_TOL)
    assert np.all(rgb[~ok] == 0)


def test_denoising_in_the_ingest_lowers_the_depth_error_and_keeps_the_rest(sim_frame):
    """TangoIngestConfig.denoise_half_window: measured depth closer to the truth (simulator ground
    truth), colours and masks untouched; off (None) is the raw measurement."""
    sim, depth_sp, colour_sp, srgb8, frame, _ = sim_frame
    T = colour_sp.packet.T_world_from_colour
    raw = ingest_tango(depth_sp.packet, srgb8, T, sim.calibration, TangoIngestConfig(denoise_half_window=None))
    den = ingest_tango(depth_sp.packet, srgb8, T, sim.calibration, TangoIngestConfig(denoise_half_window=1))
    assert raw.frame == frame
    np.testing.assert_array_equal(den.frame.known, frame.known)
    np.testing.assert_array_equal(den.frame.rgb, frame.rgb)
    assert (den.frame.depth_m[~frame.known] == 0).all()
    true = depth_sp.groundtruth["true_depth_m"]
    clean = frame.known & (depth_sp.groundtruth["flags"] == 0) & ~depth_sp.groundtruth["mixed"]
    err = lambda d: np.median(np.abs(d[clean] - true[clean]) / true[clean])  # noqa: E731
    assert err(den.frame.depth_m) < 0.6 * err(frame.depth_m)


@pytest.mark.parametrize("bad", [0, -1, True, 1.5, "2"])
def test_denoise_window_must_be_a_positive_integer(bad):
    with pytest.raises((InvalidInputError, DTypeError), match="denoise_half_window"):  # DTypeError: not an int
        TangoIngestConfig(denoise_half_window=bad)


@pytest.fixture(scope="module")
def inward_packets():
    """The third depth packet of an inward orbit (the device 1 m out, looking at the origin across the
    panels and the table) and its simultaneous colour frame: holes at many depth edges."""
    colour = ColourCameraConfig(width=320, height=240, shot_noise=0.0, read_noise=0.0)
    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit_inward"), TangoDeviceConfig(colour=colour), seed=2)
    depth_sp = colour_sp = None
    n_depth = 0
    for sp in sim.run(0.45):
        if isinstance(sp.packet, DepthPacket):
            depth_sp, n_depth = sp, n_depth + 1
        elif n_depth == 3 and sp.packet.timestamp_ns == depth_sp.packet.timestamp_ns:
            colour_sp = sp
            break
    assert colour_sp is not None
    return sim, depth_sp, colour_sp, decode_colour(colour_sp.packet)


def test_fills_across_depth_edges_are_flagged(inward_packets):
    """TangoIngestConfig.fill_max_source_ratio (default 1.5): the filled frame is eq. (1)'s, and
    ``across_edges`` flags the holes filled from sources on both sides of a depth edge; they are the
    badly filled ones (simulator ground truth). None flags nothing."""
    sim, depth_sp, colour_sp, srgb8 = inward_packets
    T = colour_sp.packet.T_world_from_colour
    plain = ingest_tango(depth_sp.packet, srgb8, T, sim.calibration, TangoIngestConfig(fill_max_source_ratio=None))
    flagged = ingest_tango(depth_sp.packet, srgb8, T, sim.calibration)
    assert TangoIngestConfig().fill_max_source_ratio == 1.5
    assert flagged.filled == plain.filled and not plain.across_edges.any()
    across = flagged.across_edges
    filled_only = flagged.filled.known & ~flagged.frame.known
    assert not (across & ~filled_only).any() and across.sum() > 100 and (filled_only & ~across).sum() > 100
    true = depth_sp.groundtruth["true_depth_m"]
    has_truth = true > 0
    rel = np.abs(flagged.filled.depth_m - true) / np.where(has_truth, true, np.inf)
    assert np.median(rel[across & has_truth]) > 3 * np.median(rel[filled_only & ~across & has_truth])
    # The same flags as fill_holes' own guard, which leaves exactly those holes unknown.
    _, guarded = fill_holes(flagged.frame.depth_m, flagged.frame.known, max_source_ratio=1.5)
    np.testing.assert_array_equal(across, filled_only & ~guarded)


@pytest.mark.parametrize("bad", [0.99, 0, -1.0, True, "1.5", float("nan")])
def test_fill_max_source_ratio_must_be_at_least_one(bad):
    with pytest.raises((InvalidInputError, DTypeError), match="fill_max_source_ratio"):
        TangoIngestConfig(fill_max_source_ratio=bad)


@pytest.mark.parametrize("method", ["telea", "ip_basic"])
def test_other_fill_methods_flag_nothing(inward_packets, method):
    sim, depth_sp, colour_sp, srgb8 = inward_packets
    res = ingest_tango(depth_sp.packet, srgb8, colour_sp.packet.T_world_from_colour, sim.calibration,
                       TangoIngestConfig(fill_method=method))
    assert res.across_edges.shape == res.frame.known.shape and not res.across_edges.any()
    assert (res.filled.known & ~res.frame.known).sum() > 100


def test_no_hole_filling_flags_nothing(inward_packets):
    sim, depth_sp, colour_sp, srgb8 = inward_packets
    res = ingest_tango(depth_sp.packet, srgb8, colour_sp.packet.T_world_from_colour, sim.calibration,
                       TangoIngestConfig(fill_method=None))
    assert res.filled is res.frame and not res.across_edges.any()


@pytest.mark.parametrize("field, bad", [("denoise_tol_rel", 0.0), ("denoise_tol_rel", 1.0), ("denoise_tol_rel", True),
                                        ("denoise_tol_rel", "0.05"), ("denoise_min_inliers", 2),
                                        ("denoise_min_inliers", 6.0), ("denoise_min_inliers", True)])
def test_denoise_parameters_are_checked(field, bad):
    with pytest.raises((InvalidInputError, DTypeError), match=field):
        TangoIngestConfig(**{field: bad})


def test_the_ingest_denoises_with_its_configured_tolerance_and_inliers(sim_frame):
    """denoise_tol_rel / denoise_min_inliers reach denoise_frame (the default 0.05 / 6 is not the
    function's own 0.04 / 6)."""
    from rgbd_envmap.depth.denoise import denoise_frame

    sim, depth_sp, colour_sp, srgb8, frame, _ = sim_frame
    T = colour_sp.packet.T_world_from_colour
    for tol, min_in in ((0.05, 6), (0.02, 12)):
        res = ingest_tango(depth_sp.packet, srgb8, T, sim.calibration,
                           TangoIngestConfig(denoise_tol_rel=tol, denoise_min_inliers=min_in))
        want = denoise_frame(frame, half_window=2, tol_rel=tol, min_inliers=min_in)
        np.testing.assert_array_equal(res.frame.depth_m, want.depth_m)
    assert not np.array_equal(denoise_frame(frame, half_window=2, tol_rel=0.05).depth_m,
                              denoise_frame(frame, half_window=2, tol_rel=0.04).depth_m)


@pytest.mark.parametrize("method", ["poses", "extrinsics"])
def test_registration_matrix_is_colour_registrations_matrix(sim_frame, method):
    from rgbd_envmap.ingest.tango import colour_registration, registration_matrix

    sim, depth_sp, colour_sp, *_ = sim_frame
    T = colour_sp.packet.T_world_from_colour
    np.testing.assert_array_equal(registration_matrix(depth_sp.packet, T, sim.calibration, method),
                                  colour_registration(depth_sp.packet, T, sim.calibration, method).matrix)
    with pytest.raises(UnknownMethodError):
        registration_matrix(depth_sp.packet, T, sim.calibration, "icp")
