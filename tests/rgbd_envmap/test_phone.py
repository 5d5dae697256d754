"""The Stray Scanner reader (rgbd_envmap.sources.stray): a capture written by hand from the format's
description reads into the pipeline's packets in our z-up world; the writer round-trips; broken files
are named."""

from __future__ import annotations

import numpy as np
import pytest

from rgbd_envmap.colour import decode_nv21
from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.sources.stray import (
    CONFIDENCE_VALUES,
    T_WORLD_FROM_ARKIT,
    StrayWriter,
    confidence_from_levels,
    depth_packet_from_image,
    is_stray_capture,
    pose_from_arkit,
    pose_to_arkit,
    read_camera_matrix,
    read_odometry,
    read_stray_capture,
)
from rgbd_envmap.types import ColourPacket, DepthPacket, Intrinsics, RigidTransform
from tests.rgbd_envmap import phone_helpers as hand


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("stray") / "capture"
    expected = hand.write_capture(root)
    return root, expected


def test_the_axis_change_is_a_rotation_taking_arkit_up_to_our_up():
    A = T_WORLD_FROM_ARKIT.rotation
    assert np.linalg.det(A) == pytest.approx(1.0)
    np.testing.assert_array_equal(A @ [0, 1, 0], [0, 0, 1])  # ARKit +y (up) → our +z
    np.testing.assert_array_equal(A @ [0, 0, -1], [0, 1, 0])  # ARKit −z (first heading) → our +y
    np.testing.assert_array_equal(A @ [1, 0, 0], [1, 0, 0])
    T = RigidTransform.from_quaternion(np.array([0.3, -1.2, 2.0]), np.array([0.1, 0.7, -0.2, 0.6]))
    back = pose_to_arkit(pose_from_arkit(T))
    np.testing.assert_allclose(back.matrix, T.matrix, atol=1e-15)
    np.testing.assert_allclose(pose_from_arkit(T).translation, [0.3, -2.0, -1.2])  # (x, −z, y)


def test_confidence_levels_map_so_that_the_default_threshold_keeps_high_only():
    c = confidence_from_levels(np.array([0, 1, 2], np.uint8))
    np.testing.assert_array_equal(c, CONFIDENCE_VALUES)
    assert list(c >= 0.7) == [False, False, True]
    assert list(c >= 0.5) == [False, True, True]  # --set ingest.confidence_threshold=0.5 admits medium
    with pytest.raises(InvalidInputError):
        confidence_from_levels(np.array([3], np.uint8))


def test_a_capture_written_by_hand_is_recognised_and_calibrated(capture_dir):
    root, _ = capture_dir
    assert is_stray_capture(root) and not is_stray_capture(root / "depth")
    cap = read_stray_capture(root, depth_rate_hz=None)
    cal = cap.calibration
    assert cal.sensor == "tango" and cap.video_size == hand.COLOUR_SIZE and cap.has_confidence
    assert (cal.colour.width, cal.colour.height) == hand.COLOUR_SIZE and cal.colour.distortion.is_zero
    np.testing.assert_allclose(cal.colour.K, hand.K, atol=1e-6)
    fx, fy, cx, cy = hand.depth_intrinsics()
    assert (cal.depth.width, cal.depth.height) == hand.DEPTH_SIZE
    np.testing.assert_allclose([cal.depth.fx, cal.depth.fy, cal.depth.cx, cal.depth.cy], [fx, fy, cx, cy], atol=1e-6)
    np.testing.assert_array_equal(cal.T_colour_from_depth.matrix, np.eye(4))
    assert cal.colour_rate_hz == pytest.approx(30.0, rel=1e-3)
    assert cap.depth_frames == list(range(len(hand.LOOKS))) and len(cap) == 2 * len(hand.LOOKS)


def test_odometry_is_read_exactly_and_turned_into_our_world(capture_dir):
    root, expected = capture_dir
    rows = read_odometry(root / "odometry.csv")
    assert [r.frame for r in rows] == list(range(len(hand.LOOKS)))
    from decimal import Decimal

    assert [r.timestamp_ns for r in rows] == [int((Decimal(t) * 10**9).to_integral_value()) for t in hand.TIMESTAMPS]
    for r, T_arkit in zip(rows, expected["poses_arkit"]):
        np.testing.assert_allclose(r.T_world_from_cam.matrix, T_WORLD_FROM_ARKIT.matrix @ T_arkit, atol=1e-12)
        assert (r.T_world_from_cam.dst, r.T_world_from_cam.src) == ("world", "colour")
    first = rows[0].T_world_from_cam
    np.testing.assert_allclose(first.translation, [0.1, -0.3, 0.2])
    np.testing.assert_allclose(first.rotation[:, 2], [0, 1, 0], atol=1e-12)  # looking along ARKit −z = our +y
    np.testing.assert_allclose(first.rotation[:, 1], [0, 0, -1], atol=1e-12)  # image down = world down
    np.testing.assert_allclose(rows[4].T_world_from_cam.rotation[:, 2], [0, 0, 1], atol=1e-12)  # looking up


def test_depth_packets_land_on_the_walls_of_the_room_in_our_world(capture_dir):
    root, expected = capture_dir
    cap = read_stray_capture(root, depth_rate_hz=None)
    for frame in cap.depth_frames:
        packet = cap.read_depth(frame)
        assert isinstance(packet, DepthPacket) and packet.timestamp_ns == cap.frame(frame).timestamp_ns
        assert len(packet.points_m) == (expected["depth_mm"][frame] > 0).sum() == 256 * 192 - 16
        world = packet.T_world_from_depth.apply(packet.points_m.astype(np.float64))
        on_wall = np.abs(world).max(axis=1)
        np.testing.assert_allclose(on_wall, hand.HALF, atol=2e-3)  # mm rounding, scaled by the ray
        # the confidence levels come through: the top rows medium, the left columns low, the rest high
        levels = expected["levels"][frame][expected["depth_mm"][frame] > 0]
        np.testing.assert_array_equal(packet.confidence, np.asarray(CONFIDENCE_VALUES, np.float32)[levels])
    # the frame looking along ARKit −z sees our +y wall; the frame looking up sees our ceiling (+z)
    ahead = cap.read_depth(0)
    w0 = ahead.T_world_from_depth.apply(ahead.points_m.astype(np.float64))
    assert np.median(w0[:, 1]) == pytest.approx(hand.HALF, abs=2e-3)
    up = cap.read_depth(4)
    w4 = up.T_world_from_depth.apply(up.points_m.astype(np.float64))
    assert np.median(w4[:, 2]) == pytest.approx(hand.HALF, abs=2e-3)


def test_packets_come_per_frame_depth_first_with_the_walls_colours(capture_dir):
    root, _ = capture_dir
    cap = read_stray_capture(root, depth_rate_hz=None)
    kinds, frames = [], []
    for packet, row in cap.packets():
        kinds.append(packet.kind)
        frames.append(row.frame)
        assert packet.timestamp_ns == row.timestamp_ns
        if isinstance(packet, ColourPacket):
            np.testing.assert_array_equal(packet.T_world_from_colour.matrix, row.T_world_from_cam.matrix)
            rgb = decode_nv21(packet.nv21, packet.height, packet.width).astype(int)
            centre = rgb[110:130, 150:170].reshape(-1, 3)
            want = hand.WALLS[{0: ("z", -1), 1: ("x", -1), 2: ("z", 1), 3: ("x", 1), 4: ("y", 1), 5: ("y", -1)}[row.frame]]
            assert np.abs(np.median(centre, axis=0) - want).max() <= 4
    assert kinds == ["depth", "colour"] * len(hand.LOOKS)
    assert frames == [f for f in range(len(hand.LOOKS)) for _ in range(2)]
    assert not any(cap.skipped.values())


def _has_encoder(name: str) -> bool:
    import subprocess

    import imageio_ffmpeg

    out = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-encoders"], capture_output=True, text=True).stdout
    return f" {name} " in out


@pytest.mark.skipif(not _has_encoder("libx265"), reason="this ffmpeg has no HEVC encoder")
def test_an_iphone_like_hevc_bt709_video_decodes_to_the_right_colours(tmp_path):
    # A BT.709 stream read as BT.601 puts these walls 10–20 codes off; the reader honours the tag.
    hand.write_capture(tmp_path / "c", video="hevc")
    cap = read_stray_capture(tmp_path / "c", depth_rate_hz=None)
    walls = {0: ("z", -1), 1: ("x", -1), 3: ("x", 1), 4: ("y", 1)}
    for packet, row in cap.packets():
        if isinstance(packet, ColourPacket) and row.frame in walls:
            rgb = decode_nv21(packet.nv21, packet.height, packet.width).astype(int)
            centre = np.median(rgb[110:130, 150:170].reshape(-1, 3), axis=0)
            assert np.abs(centre - hand.WALLS[walls[row.frame]]).max() <= 4, (row.frame, centre)


def test_depth_is_taken_at_the_requested_rate_and_the_video_can_be_decoded_smaller(capture_dir):
    root, _ = capture_dir
    cap = read_stray_capture(root, depth_rate_hz=10.0, colour_size=(160, 120))
    assert cap.depth_frames == [0, 3] and cap.skipped["depth_not_taken"] == 4
    assert cap.calibration.depth_rate_hz == pytest.approx(10.0, rel=1e-3)
    assert (cap.calibration.colour.width, cap.calibration.colour.height) == (160, 120)
    np.testing.assert_allclose(cap.calibration.colour.K, Intrinsics(320, 240, *hand.K[[0, 1, 0, 1], [0, 1, 2, 2]]).scaled(160, 120).K)
    # the depth intrinsics stay those of the full-size camera matrix
    np.testing.assert_allclose(cap.calibration.depth.fx, hand.depth_intrinsics()[0])
    packets = [p for p, _ in cap.packets()]
    assert [p.kind for p in packets].count("depth") == 2
    assert all(p.nv21.shape == (180, 160) for p in packets if p.kind == "colour")


def test_a_capture_without_confidence_counts_every_depth_pixel_as_high(tmp_path):
    hand.write_capture(tmp_path / "c", confidence=False)
    cap = read_stray_capture(tmp_path / "c", depth_rate_hz=None)
    assert not cap.has_confidence
    assert (cap.read_depth(0).confidence == 1.0).all()


def test_the_writer_round_trips_poses_depth_and_colour(tmp_path):
    from rgbd_envmap.colour import encode_nv21
    from rgbd_envmap.geometry import look_at

    intr = Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:48, 0:64]
    images, poses, depths = [], [], []
    with StrayWriter(tmp_path / "w", intr, depth_size=(32, 24)) as w:
        for i in range(4):
            T = look_at(np.array([0.2 * i, -0.1, 1.3]), np.array([1.0, 2.0, 1.0 + 0.1 * i]))
            rgb = np.stack([x * 3 + 10 * i, y * 4, np.full_like(x, 120)], axis=-1).astype(np.uint8)
            nv21 = encode_nv21(rgb)
            assert w.write_colour(5 * 10**9 + i * 40_000_000, T, nv21) == i
            images.append(nv21)
            poses.append(T)
            d = rng.uniform(0.3, 4.0, (24, 32)).astype(np.float32)
            w.write_depth(i, d, d < 3.5, rng.integers(0, 3, (24, 32)))
            depths.append(d)
    cap = read_stray_capture(tmp_path / "w", depth_rate_hz=None)
    assert cap.calibration.colour == intr and cap.calibration.depth == intr.scaled(32, 24)
    assert cap.calibration.colour_rate_hz == pytest.approx(25.0)
    colour = [(p, r) for p, r in cap.packets() if p.kind == "colour"]
    assert len(colour) == 4
    for (p, r), nv21, T in zip(colour, images, poses):
        np.testing.assert_allclose(p.T_world_from_colour.matrix, T.matrix, atol=1e-14)
        a = decode_nv21(p.nv21, 48, 64).astype(int)
        b = decode_nv21(nv21, 48, 64).astype(int)
        assert np.abs(a - b).mean() < 1.5 and np.abs(a - b).max() <= 8  # lossless video; two YUV ↔ RGB roundings
    depth_m, known, _ = cap.read_depth_image(2)
    np.testing.assert_array_equal(known, depths[2] < 3.5)
    np.testing.assert_allclose(depth_m[known], depths[2][known], atol=5e-4)


def test_the_writer_refuses_distortion_and_an_existing_capture(tmp_path):
    from rgbd_envmap.types import Distortion

    with pytest.raises(InvalidInputError, match="distortion"):
        StrayWriter(tmp_path / "a", Intrinsics(64, 48, 50, 50, 31.5, 23.5, Distortion(0.1)))
    StrayWriter(tmp_path / "b", Intrinsics(64, 48, 50, 50, 31.5, 23.5)).close()
    with pytest.raises(InvalidInputError, match="overwrite"):
        StrayWriter(tmp_path / "b", Intrinsics(64, 48, 50, 50, 31.5, 23.5))


def test_depth_packet_from_image_unprojects_known_pixels():
    intr = Intrinsics(4, 3, 2.0, 2.0, 1.5, 1.0)
    depth = np.full((3, 4), 2.0, np.float32)
    known = np.zeros((3, 4), bool)
    known[1, 3] = known[0, 0] = True
    p = depth_packet_from_image(7, depth, known, np.full((3, 4), 0.5), intr, RigidTransform.identity())
    np.testing.assert_allclose(p.points_m, [[2 * (0 - 1.5) / 2, 2 * (0 - 1.0) / 2, 2.0], [2 * (3 - 1.5) / 2, 0.0, 2.0]])
    assert (p.T_world_from_depth.dst, p.T_world_from_depth.src) == ("world", "depth")


@pytest.mark.parametrize("text, match", [
    ("timestamp, frame, x, y, z, qx, qy, qz\n1.0, 0, 0, 0, 0, 0, 0, 0\n", "header lacks"),
    ("timestamp, frame, x, y, z, qx, qy, qz, qw\n1.0, 0, 0, 0, 0, 0, 0, 0, 1\n1.0, 1, 0, 0, 0, 0, 0, 0, 1\n", "does not increase"),
    ("timestamp, frame, x, y, z, qx, qy, qz, qw\n1.0, 0, 0, 0, 0, 0, 0, 0, 1\n2.0, 0, 0, 0, 0, 0, 0, 0, 1\n", "appears twice"),
    ("timestamp, frame, x, y, z, qx, qy, qz, qw\n1.0, 0, nan, 0, 0, 0, 0, 0, 1\n", "NaN"),
    ("timestamp, frame, x, y, z, qx, qy, qz, qw\n1.0, 0, 0, 0, 0, 0, 0, 0, 2\n", "quaternion norm"),
    ("timestamp, frame, x, y, z, qx, qy, qz, qw\n1.0, 0, 0, 0, 0, 0, 0, 1\n", "expected 9 fields"),
    ("timestamp, frame, x, y, z, qx, qy, qz, qw\nabc, 0, 0, 0, 0, 0, 0, 0, 1\n", "malformed timestamp"),
])
def test_broken_odometry_names_the_file_and_line(tmp_path, text, match):
    path = tmp_path / "odometry.csv"
    path.write_text(text)
    with pytest.raises(LogFormatError, match=match) as info:
        read_odometry(path)
    assert "odometry.csv" in str(info.value)


def test_a_camera_matrix_with_skew_or_missing_rows_is_refused(tmp_path):
    path = tmp_path / "camera_matrix.csv"
    path.write_text("100, 1, 50\n0, 100, 40\n0, 0, 1\n")
    with pytest.raises(LogFormatError, match="no skew"):
        read_camera_matrix(path)
    path.write_text("100, 0, 50\n0, 100, 40\n")
    with pytest.raises(LogFormatError, match="three rows"):
        read_camera_matrix(path)


def test_broken_depth_and_confidence_files_are_named(capture_dir, tmp_path):
    import shutil

    import cv2

    root, _ = capture_dir
    copy = tmp_path / "c"
    shutil.copytree(root, copy)
    victim = copy / "depth" / "000002.png"
    victim.write_bytes(victim.read_bytes()[:50])
    assert cv2.imwrite(str(copy / "confidence" / "000003.png"), np.full((192, 256), 3, np.uint8))
    cap = read_stray_capture(copy, depth_rate_hz=None)
    with pytest.raises(LogFormatError, match="000002.png"):
        cap.read_depth(2)
    with pytest.raises(LogFormatError, match="levels 0, 1 or 2"):
        cap.read_depth(3)
    errors = []
    kinds = [p.kind for p, _ in cap.packets(lambda kind, exc: errors.append((kind, str(exc))))]
    assert kinds.count("colour") == 6 and kinds.count("depth") == 4
    assert [k for k, _ in errors] == ["depth", "depth"] and "000002.png" in errors[0][1]
    with pytest.raises(LogFormatError):
        list(cap.packets())


def test_a_missing_video_or_a_principal_point_off_the_frame_is_refused(capture_dir, tmp_path):
    import shutil

    root, _ = capture_dir
    copy = tmp_path / "c"
    shutil.copytree(root, copy)
    (copy / "camera_matrix.csv").write_text("260, 0, 700\n0, 260, 118\n0, 0, 1\n")
    with pytest.raises(LogFormatError, match="principal point"):
        read_stray_capture(copy)
    (copy / "rgb.mp4").unlink()
    with pytest.raises(LogFormatError, match="rgb.mp4"):
        read_stray_capture(copy)
