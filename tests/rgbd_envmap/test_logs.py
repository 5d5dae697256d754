"""Tests for rgbd_envmap.logs: round trips, independent readers (open3d, OpenCV) and broken sessions.

Pose matrices are compared to 1e-12 because the log stores a quaternion as text (%.17g), not the matrix.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.logs import SessionLog, SessionWriter, format_timestamp, parse_timestamp
from rgbd_envmap.types import Calibration, ColourPacket, DepthPacket, Intrinsics, RigidTransform

W, H = 32, 24


def make_calibration() -> Calibration:
    T = RigidTransform.from_rt(Rotation.from_euler("xyz", [0.01, -0.02, 0.03]).as_matrix(), [0.01, 0.0, -0.002])
    return Calibration("tango", Intrinsics(16, 12, 14.0, 14.5, 7.5, 5.5), Intrinsics(W, H, 30.0, 30.0, 15.5, 11.5), T)


def random_pose(rng: np.random.Generator) -> RigidTransform:
    R = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    return RigidTransform.from_rt(R, rng.normal(size=3) * 3.0)


def depth_packet(rng, ns: int, n: int) -> DepthPacket:
    return DepthPacket(ns, rng.normal(size=(n, 3)).astype(np.float32), rng.random(n).astype(np.float32), random_pose(rng))


def colour_packet(rng, ns: int, w: int = W, h: int = H) -> ColourPacket:
    return ColourPacket(ns, rng.integers(0, 256, (h * 3 // 2, w), dtype=np.uint8), random_pose(rng))


@pytest.fixture
def session(tmp_path: Path):
    """A written session: 4 depth packets (one empty cloud), 5 colour packets, one depth/colour tie."""
    rng = np.random.default_rng(7)
    packets = [depth_packet(rng, 1_000, 50), colour_packet(rng, 1_500), depth_packet(rng, 2_000, 0),
               colour_packet(rng, 2_000), depth_packet(rng, 2_000_000_001, 7), colour_packet(rng, 3 * 10**9),
               colour_packet(rng, 3 * 10**9 + 1), depth_packet(rng, 4 * 10**9, 300), colour_packet(rng, 5 * 10**9)]
    true_poses = {p.timestamp_ns: random_pose(rng) for p in packets}
    gts = {p.timestamp_ns: {"depth_m": rng.random((3, 4)).astype(np.float32), "ids": np.arange(5, dtype=np.int16)}
           for p in packets if p.kind == "depth"}
    root = tmp_path / "session"
    with SessionWriter(root, make_calibration()) as w:
        for p in packets:
            w.write(p, true_pose=true_poses[p.timestamp_ns], groundtruth=gts.get(p.timestamp_ns) if p.kind == "depth" else None)
    return root, packets, true_poses, gts


def pose_of(p):
    return p.T_world_from_depth if p.kind == "depth" else p.T_world_from_colour


def assert_same_packet(a, b):
    assert type(a) is type(b) and a.timestamp_ns == b.timestamp_ns
    if a.kind == "depth":
        assert a.points_m.dtype == b.points_m.dtype == np.float32 and a.points_m.shape == b.points_m.shape
        assert a.points_m.tobytes() == b.points_m.tobytes() and a.confidence.tobytes() == b.confidence.tobytes()
    else:
        assert a.nv21.dtype == b.nv21.dtype == np.uint8 and np.array_equal(a.nv21, b.nv21)
    np.testing.assert_allclose(pose_of(a).matrix, pose_of(b).matrix, rtol=0, atol=1e-12)


# --- round trips -----------------------------------------------------------------------------------


def test_round_trip_packets_in_merged_order(session):
    root, packets, _, _ = session
    log = SessionLog.open(root)
    assert len(log) == len(packets) == 9
    assert log.depth_timestamps_ns.dtype == np.int64
    assert log.depth_timestamps_ns.tolist() == [p.timestamp_ns for p in packets if p.kind == "depth"]
    assert log.colour_timestamps_ns.tolist() == [p.timestamp_ns for p in packets if p.kind == "colour"]
    read = list(log)
    assert [p.kind for p in read] == [p.kind for p in packets]  # tie at 2000 ns: depth first
    for a, b in zip(packets, read):
        assert_same_packet(a, b)
    assert read[2].points_m.shape == (0, 3)
    assert log.calibration.to_dict() == make_calibration().to_dict()
    assert pose_of(read[0]).dst == "world" and pose_of(read[0]).src == "depth"


def test_ground_truth_and_true_poses_round_trip(session):
    root, packets, true_poses, gts = session
    log = SessionLog.open(root)
    for kind in ("depth", "colour"):
        read = log.true_poses(kind)
        want = {p.timestamp_ns: true_poses[p.timestamp_ns] for p in packets if p.kind == kind}
        assert sorted(read) == sorted(want)
        for ns, T in want.items():
            np.testing.assert_allclose(read[ns].matrix, T.matrix, rtol=0, atol=1e-12)
    for ns, arrays in gts.items():
        got = log.groundtruth("depth", ns)
        assert set(got) == set(arrays)
        for k, a in arrays.items():
            assert got[k].dtype == a.dtype and np.array_equal(got[k], a)
    assert log.groundtruth("colour", 1_500) == {}
    assert log.groundtruth("depth", 123) == {}


def test_session_without_ground_truth_has_none(tmp_path):
    rng = np.random.default_rng(1)
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(depth_packet(rng, 5, 3))
    log = SessionLog.open(tmp_path / "s")
    assert log.true_poses("depth") == {} and log.groundtruth("depth", 5) == {}
    assert len(log) == 1 and log.colour_timestamps_ns.shape == (0,)
    with pytest.raises(InvalidInputError, match="kind"):
        log.true_poses("rgb")


def test_open3d_reads_the_ply(session):
    o3d = pytest.importorskip("open3d")
    root, packets, _, _ = session
    for p in packets:
        if p.kind == "depth" and len(p.points_m):
            pcd = o3d.io.read_point_cloud(str(root / "depth" / f"{p.timestamp_ns}.ply"))
            xyz = np.asarray(pcd.points)
            assert xyz.shape == p.points_m.shape
            assert np.array_equal(xyz, p.points_m.astype(np.float64))


def test_opencv_reads_the_png(session):
    root, packets, _, _ = session
    for p in packets:
        if p.kind == "colour":
            img = cv2.imread(str(root / "colour" / f"{p.timestamp_ns}.png"), cv2.IMREAD_UNCHANGED)
            assert img.dtype == np.uint8 and img.shape == (H * 3 // 2, W) and np.array_equal(img, p.nv21)


def test_files_follow_the_documented_text_format(session):
    root, packets, _, _ = session
    lines = [l for l in (root / "depth.txt").read_text().splitlines() if not l.startswith("#")]
    assert lines[0] == "0.000001000 depth/1000.ply"
    pose = [l for l in (root / "colour_poses.txt").read_text().splitlines() if not l.startswith("#")][0].split()
    assert pose[0] == "0.000001500" and len(pose) == 8 and float(pose[7]) >= 0


@pytest.mark.parametrize("ns", [0, 1, 999_999_999, 10**9, 2**62, 2**63 - 1])
def test_extreme_timestamps_survive_exactly(tmp_path, ns):
    rng = np.random.default_rng(ns % 1000)
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(depth_packet(rng, ns, 2))
        w.write(colour_packet(rng, ns))
    log = SessionLog.open(tmp_path / "s")
    assert log.depth_timestamps_ns.tolist() == [ns] and log.colour_timestamps_ns.tolist() == [ns]
    assert [p.timestamp_ns for p in log] == [ns, ns]


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**63 - 1))
def test_timestamp_text_round_trip(ns):
    text = format_timestamp(ns)
    assert len(text.split(".")[1]) == 9 and parse_timestamp(text) == ns


def test_timestamp_text_edge_cases():
    assert format_timestamp(1) == "0.000000001" and format_timestamp(999_999_999) == "0.999999999"
    assert parse_timestamp("1305031102.175304") == 1305031102_175304000  # TUM benchmark: 6 decimals
    for bad in ("-1.0", "1.0000000001", "1e9", "", "1.", str(2**63 // 10**9 + 1)):
        with pytest.raises(ValueError):
            parse_timestamp(bad)
    with pytest.raises(InvalidInputError):
        format_timestamp(-1)


# --- writer errors ---------------------------------------------------------------------------------


def test_writer_rejects_non_increasing_timestamps(tmp_path):
    rng = np.random.default_rng(2)
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(depth_packet(rng, 100, 2))
        w.write(colour_packet(rng, 50))  # other stream: independent
        for ns in (100, 99):
            with pytest.raises(InvalidInputError, match=rf"100.*{ns}"):
                w.write(depth_packet(rng, ns, 2))
    assert SessionLog.open(tmp_path / "s").depth_timestamps_ns.tolist() == [100]


def test_writer_rejects_wrong_colour_size(tmp_path):
    rng = np.random.default_rng(3)
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        with pytest.raises(InvalidInputError, match="nv21"):
            w.write(colour_packet(rng, 1, w=W + 2))
    assert not any((tmp_path / "s" / "colour").iterdir())


def test_writer_refuses_non_empty_dir_without_overwrite(tmp_path):
    root = tmp_path / "s"
    root.mkdir()
    (root / "notes.txt").write_text("keep me")
    with pytest.raises(LogFormatError, match="not empty"):
        SessionWriter(root, make_calibration())
    rng = np.random.default_rng(4)
    with SessionWriter(root, make_calibration(), overwrite=True) as w:
        w.write(depth_packet(rng, 9, 1))
    with SessionWriter(root, make_calibration(), overwrite=True) as w:  # replaces the previous session
        w.write(colour_packet(rng, 10))
    log = SessionLog.open(root)
    assert len(log) == 1 and (root / "notes.txt").read_text() == "keep me"


def test_partial_session_is_readable_before_close(tmp_path):
    rng = np.random.default_rng(5)
    w = SessionWriter(tmp_path / "s", make_calibration())
    w.write(depth_packet(rng, 1, 4))
    w.write(colour_packet(rng, 2))
    assert len(SessionLog.open(tmp_path / "s")) == 2  # lines are flushed as packets arrive
    w.close()
    with pytest.raises(InvalidInputError, match="closed"):
        w.write(depth_packet(rng, 3, 1))


# --- reader errors: each names the file (and line) -------------------------------------------------


def replace_line(path: Path, lineno: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[lineno - 1] = text
    path.write_text("\n".join(lines) + "\n")


def data_lines(path: Path) -> list[int]:
    """1-based numbers of the non-comment lines."""
    return [i for i, l in enumerate(path.read_text().splitlines(), 1) if l.strip() and not l.startswith("#")]


def test_missing_calibration(session):
    root = session[0]
    (root / "calibration.json").unlink()
    with pytest.raises(LogFormatError, match="calibration.json"):
        SessionLog.open(root)


def test_calibration_with_wrong_format_tag(session):
    root = session[0]
    (root / "calibration.json").write_text('{"format": "other", "version": 1}')
    with pytest.raises(LogFormatError, match="calibration.json"):
        SessionLog.open(root)


def test_missing_ply_listed_in_index(session):
    root = session[0]
    (root / "depth" / "2000.ply").unlink()
    log = SessionLog.open(root)  # lazy: opening only reads the indices
    with pytest.raises(LogFormatError, match=r"2000\.ply"):
        log.read_depth(1)


def test_truncated_png(session):
    root = session[0]
    path = root / "colour" / "1500.png"
    path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    with pytest.raises(LogFormatError, match=r"1500\.png"):
        SessionLog.open(root).read_colour(0)


def test_png_of_wrong_shape(session):
    root = session[0]
    cv2.imwrite(str(root / "colour" / "1500.png"), np.zeros((H * 3 // 2, W + 2), np.uint8))
    with pytest.raises(LogFormatError, match=r"1500\.png.*\(36, 32\)"):
        SessionLog.open(root).read_colour(0)


def test_truncated_ply(session):
    root = session[0]
    path = root / "depth" / "1000.ply"
    path.write_bytes(path.read_bytes()[:-5])
    with pytest.raises(LogFormatError, match=r"1000\.ply.*truncated"):
        SessionLog.open(root).read_depth(0)


@pytest.mark.parametrize("old,new", [("binary_little_endian", "ascii"), ("property float z", "property double z"),
                                     ("property float confidence", "property float intensity")])
def test_ply_with_other_layout_rejected(session, old, new):
    root = session[0]
    path = root / "depth" / "1000.ply"
    path.write_bytes(path.read_bytes().replace(old.encode(), new.encode(), 1))
    with pytest.raises(LogFormatError, match=r"1000\.ply"):
        SessionLog.open(root).read_depth(0)


def test_ply_properties_in_other_order(tmp_path):
    """A PLY with the same properties reordered (confidence first) reads to the same packet."""
    n = 5
    rng = np.random.default_rng(6)
    pts, conf = rng.normal(size=(n, 3)).astype(np.float32), rng.random(n).astype(np.float32)
    body = np.empty(n, dtype=[("confidence", "<f4"), ("z", "<f4"), ("x", "<f4"), ("y", "<f4")])
    body["x"], body["y"], body["z"], body["confidence"] = pts.T[0], pts.T[1], pts.T[2], conf
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(depth_packet(rng, 1, n))
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 5\n" + "".join(
        f"property float {f}\n" for f in body.dtype.names) + "end_header\n"
    (tmp_path / "s" / "depth" / "1.ply").write_bytes(header.encode() + body.tobytes())
    p = SessionLog.open(tmp_path / "s").read_depth(0)
    assert np.array_equal(p.points_m, pts) and np.array_equal(p.confidence, conf)


def test_unsorted_timestamps_in_depth_index(session):
    root = session[0]
    idx = root / "depth.txt"
    first, second = data_lines(idx)[:2]
    lines = idx.read_text().splitlines()
    lines[first - 1], lines[second - 1] = lines[second - 1], lines[first - 1]
    idx.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogFormatError, match=rf"depth\.txt, line {second}\b"):
        SessionLog.open(root)


def test_duplicate_timestamp_in_colour_index(session):
    root = session[0]
    idx = root / "colour.txt"
    first, second = data_lines(idx)[:2]
    replace_line(idx, second, idx.read_text().splitlines()[first - 1])
    with pytest.raises(LogFormatError, match=rf"colour\.txt, line {second}\b"):
        SessionLog.open(root)


def test_nan_in_pose_line(session):
    root = session[0]
    poses = root / "depth_poses.txt"
    n = data_lines(poses)[2]
    fields = poses.read_text().splitlines()[n - 1].split()
    fields[2] = "nan"
    replace_line(poses, n, " ".join(fields))
    with pytest.raises(LogFormatError, match=rf"depth_poses\.txt, line {n}\b.*NaN"):
        SessionLog.open(root)


def test_non_unit_quaternion(session):
    root = session[0]
    poses = root / "colour_poses.txt"
    n = data_lines(poses)[0]
    replace_line(poses, n, "0.000001500 0 0 0 0 0 0 2")
    with pytest.raises(LogFormatError, match=rf"colour_poses\.txt, line {n}\b.*quaternion"):
        SessionLog.open(root)


@pytest.mark.parametrize("name,fields", [("depth.txt", "0.000001000"), ("depth_poses.txt", "0.000001000 1 2 3 0 0 0"),
                                         ("colour.txt", "0.000001500 colour/1500.png extra")])
def test_malformed_line_wrong_field_count(session, name, fields):
    root = session[0]
    path = root / name
    n = data_lines(path)[0]
    replace_line(path, n, fields)
    with pytest.raises(LogFormatError, match=re.escape(name) + rf", line {n}\b.*fields"):
        SessionLog.open(root)


def test_index_entry_without_pose(session):
    root = session[0]
    poses = root / "colour_poses.txt"
    n = data_lines(poses)[1]
    replace_line(poses, n, "# removed")
    with pytest.raises(LogFormatError, match=rf"colour\.txt, line {data_lines(root / 'colour.txt')[1]}\b.*pose"):
        SessionLog.open(root)


def test_missing_index_file(session):
    root = session[0]
    (root / "colour.txt").unlink()
    with pytest.raises(LogFormatError, match=r"colour\.txt: missing"):
        SessionLog.open(root)


@pytest.mark.parametrize("garbage", [b"not an npz", b"PK\x03\x04broken"])
def test_corrupt_ground_truth_npz(session, garbage):
    root = session[0]
    (root / "groundtruth" / "depth" / "1000.npz").write_bytes(garbage)
    with pytest.raises(LogFormatError, match=r"1000\.npz"):
        SessionLog.open(root).groundtruth("depth", 1000)


def test_ground_truth_keys_that_clash_with_savez_arguments(tmp_path):
    rng = np.random.default_rng(8)
    arrays = {"file": np.arange(3), "allow_pickle": np.ones((2, 2), np.float64)}
    with SessionWriter(tmp_path / "s", make_calibration()) as w:
        w.write(depth_packet(rng, 1, 1), groundtruth=arrays)
        with pytest.raises(InvalidInputError, match="groundtruth"):
            w.write(depth_packet(rng, 2, 1), groundtruth={"o": np.array([object()])})
    got = SessionLog.open(tmp_path / "s").groundtruth("depth", 1)
    assert set(got) == set(arrays) and all(np.array_equal(got[k], arrays[k]) for k in arrays)


def _rewrite_ply(path: Path, points: np.ndarray, confidence: np.ndarray) -> None:
    from rgbd_envmap.logs import _ply_bytes  # the writer's own layout (test-only use of a private helper)

    path.write_bytes(_ply_bytes(points.astype(np.float32), confidence.astype(np.float32)))


def test_non_finite_points_are_dropped_and_counted_per_file(tmp_path):
    root, packets = tmp_path / "s", []
    rng = np.random.default_rng(7)
    with SessionWriter(root, make_calibration()) as w:
        for k in range(3):
            p = depth_packet(rng, 1000 * (k + 1), 50)
            w.write(p)
            packets.append(p)
    log = SessionLog.open(root)
    rel = sorted((root / "depth").iterdir())
    pts, conf = packets[1].points_m.copy(), packets[1].confidence.copy()
    pts[3, 1], pts[10, 2], conf[20] = np.nan, np.inf, np.nan
    _rewrite_ply(rel[1], pts, conf)
    _rewrite_ply(rel[2], np.full((5, 3), np.nan), np.ones(5))
    got = log.read_depth(1)
    keep = np.ones(50, bool)
    keep[[3, 10, 20]] = False
    np.testing.assert_array_equal(got.points_m, packets[1].points_m[keep])
    np.testing.assert_array_equal(got.confidence, packets[1].confidence[keep])
    assert log.dropped_points == {str(rel[1].relative_to(root)): 3}
    with pytest.raises(LogFormatError, match=r"depth/.*: 5 of 5 points hold NaN or inf \(every point\)"):
        log.read_depth(2)  # an all-NaN packet: the replay skips and counts it
    with pytest.raises(LogFormatError, match=r"3 of 50 points hold NaN or inf"):
        log.read_depth(1, strict=True)
    assert log.read_depth(0).points_m.shape == (50, 3)  # a clean packet is untouched


def test_an_empty_index_is_a_warning(tmp_path):
    root = tmp_path / "s"
    rng = np.random.default_rng(8)
    with SessionWriter(root, make_calibration()) as w:
        w.write(colour_packet(rng, 10))
    log = SessionLog.open(root)
    assert len(log.warnings) == 1 and "depth.txt: empty index" in log.warnings[0]
