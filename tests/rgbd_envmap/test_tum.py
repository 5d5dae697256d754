"""Tests for rgbd_envmap.tum: round trips, the benchmark's own text layout, association by nearest
timestamp with jitter, and every documented bad input (errors naming the file and line).

Pose matrices are compared to 1e-12 (the file stores a quaternion as %.17g text, not the matrix).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    LogFormatError,
    RangeError,
    ShapeError,
    UnknownMethodError,
)
from rgbd_envmap.tum import (
    TUM_DEFAULT_INTRINSICS,
    TUM_DEPTH_CORRECTION,
    TUM_INTRINSICS,
    TumFrame,
    TumTrajectory,
    read_tum_sequence,
    tum_camera_from_name,
    write_tum_sequence,
)
from rgbd_envmap.types import Calibration, Intrinsics, RigidTransform

W, H = 20, 16
INTR = Intrinsics(W, H, 18.0, 18.5, 9.5, 7.5)


def random_pose(rng: np.random.Generator) -> RigidTransform:
    R = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    return RigidTransform.from_rt(R, rng.normal(size=3) * 2.0, "world", "colour")


def random_frame(rng: np.random.Generator, ns: int, w: int = W, h: int = H) -> TumFrame:
    depth = rng.uniform(0.3, 12.0, (h, w)).astype(np.float32)
    known = rng.random((h, w)) > 0.3
    depth[~known] = np.nan  # anything may sit under unknown pixels; the writer stores 0
    return TumFrame(ns, rng.integers(0, 256, (h, w, 3), dtype=np.uint8), depth, known, random_pose(rng))


def quantised(depth_m: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Independent expectation: the nearest 1/5000 m, as float32, 0 where unknown."""
    units = np.where(known, np.round(np.nan_to_num(depth_m.astype(np.float64)) * 5000.0), 0.0)
    return (units / 5000.0).astype(np.float32)


@pytest.fixture
def written(tmp_path):
    rng = np.random.default_rng(11)
    stamps = [1_305_031_102_175_304_000 + k * 33_333_000 for k in range(5)]
    frames = [random_frame(rng, ns) for ns in stamps]
    root = tmp_path / "seq"
    assert write_tum_sequence(root, iter(frames), INTR) == 5
    return root, frames


def write_text(path: Path, lines: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def write_png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, png = cv2.imencode(".png", img)
    assert ok
    path.write_bytes(png.tobytes())


# --- round trips -----------------------------------------------------------------------------------


def test_round_trip_arrays_poses_and_timestamps(written):
    root, frames = written
    seq = read_tum_sequence(root)
    assert len(seq) == 5 and seq.skipped == {"no_rgb": 0, "no_pose": 0, "rgb_unused": 0}
    assert seq.intrinsics == INTR and seq.calibration is not None and seq.calibration.sensor == "kinect"
    assert seq.timestamps_ns.tolist() == [f.timestamp_ns for f in frames]
    for a, b in zip(frames, seq):
        assert b.timestamp_ns == a.timestamp_ns and b.rgb_timestamp_ns == a.timestamp_ns
        assert b.rgb.dtype == np.uint8 and np.array_equal(b.rgb, a.rgb)
        assert b.depth_m.dtype == np.float32 and np.array_equal(b.depth_m, quantised(a.depth_m, a.known))
        assert b.known.dtype == bool and np.array_equal(b.known, a.known)
        np.testing.assert_allclose(b.T_world_from_cam.matrix, a.T_world_from_cam.matrix, rtol=0, atol=1e-12)
        assert (b.T_world_from_cam.dst, b.T_world_from_cam.src) == ("world", "colour")
        assert np.all(np.abs(b.depth_m - a.depth_m)[a.known] <= 1e-4 + 1e-6)  # half a unit, plus float32 rounding
        assert not b.depth_m.flags.writeable


def test_second_round_trip_is_bit_exact(written, tmp_path):
    root, _ = written
    first = list(read_tum_sequence(root))
    write_tum_sequence(tmp_path / "again", first, INTR)
    for a, b in zip(first, read_tum_sequence(tmp_path / "again")):
        assert np.array_equal(a.depth_m, b.depth_m) and np.array_equal(a.rgb, b.rgb) and np.array_equal(a.known, b.known)


def test_files_follow_the_benchmark_layout(written):
    root, frames = written
    depth_lines = [l for l in (root / "depth.txt").read_text().splitlines() if not l.startswith("#")]
    assert depth_lines[0] == "1305031102.175304 depth/1305031102.175304.png"  # 6 decimals, as the benchmark
    gt = [l.split() for l in (root / "groundtruth.txt").read_text().splitlines() if not l.startswith("#")]
    assert len(gt) == 5 and all(len(r) == 8 for r in gt) and gt[0][0] == "1305031102.175304"
    png = cv2.imread(str(root / depth_lines[0].split()[1]), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and png.shape == (H, W)
    f = frames[0]
    assert np.array_equal(png[f.known], np.round(f.depth_m[f.known].astype(np.float64) * 5000).astype(np.uint16))
    assert np.all(png[~f.known] == 0)
    bgr = cv2.imread(str(root / "rgb" / "1305031102.175304.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(bgr[..., ::-1], f.rgb)  # OpenCV reads BGR: the file holds RGB
    cal = json.loads((root / "calibration.json").read_text())
    assert cal["format"] == "rgbd-envmap-tum" and cal["sensor"] == "kinect" and cal["depth"] == cal["colour"]


def test_nanosecond_timestamps_need_nine_decimals(tmp_path):
    rng = np.random.default_rng(1)
    frames = [random_frame(rng, ns) for ns in (0, 1, 33_333_333)]
    with pytest.raises(InvalidInputError, match=r"frames\[1\].timestamp_ns.*timestamp_decimals=9"):
        write_tum_sequence(tmp_path / "a", frames, INTR)
    write_tum_sequence(tmp_path / "b", frames, INTR, timestamp_decimals=9)
    seq = read_tum_sequence(tmp_path / "b", max_dt_s=0.0)
    assert seq.timestamps_ns.tolist() == [0, 1, 33_333_333] and len(seq) == 3


def test_default_intrinsics_without_calibration_json(tmp_path):
    rng = np.random.default_rng(2)
    frame = random_frame(rng, 10**9, 640, 480)
    write_tum_sequence(tmp_path / "s", [frame], TUM_DEFAULT_INTRINSICS, calibration_json=False)
    seq = read_tum_sequence(tmp_path / "s")
    assert seq.calibration is None and seq.intrinsics == Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    assert np.array_equal(seq.load(0).rgb, frame.rgb)
    override = Intrinsics(640, 480, 517.3, 516.5, 318.6, 255.3)
    assert read_tum_sequence(tmp_path / "s", intrinsics=override).intrinsics == override


def test_benchmark_style_files_parse(tmp_path):
    """Lines exactly as the public benchmark writes them: three header comments, 6-decimal image
    stamps, 4-decimal poses at another rate, and paths under rgb/ and depth/."""
    root = tmp_path / "fr1"
    write_text(root / "rgb.txt", ["# color images", "# file: 'rgbd_dataset_freiburg1_xyz.bag'", "# timestamp filename",
                                  "1305031102.175304 rgb/1305031102.175304.png", "1305031102.211214 rgb/1305031102.211214.png"])
    write_text(root / "depth.txt", ["# depth maps", "# file: 'rgbd_dataset_freiburg1_xyz.bag'", "# timestamp filename",
                                    "1305031102.160407 depth/1305031102.160407.png", "1305031102.194330 depth/1305031102.194330.png"])
    write_text(root / "groundtruth.txt", [
        "# ground truth trajectory", "# file: 'rgbd_dataset_freiburg1_xyz.bag'", "# timestamp tx ty tz qx qy qz qw",
        "1305031102.1600 1.3405 0.6266 1.6575 0.6574 0.6126 -0.2949 -0.3248",
        "1305031102.1700 1.3401 0.6261 1.6574 0.6573 0.6127 -0.2950 -0.3248",
        "1305031102.1900 1.3397 0.6257 1.6575 0.6572 0.6129 -0.2951 -0.3247",
    ])
    for name in ("1305031102.160407", "1305031102.194330"):
        write_png(root / "depth" / f"{name}.png", np.full((480, 640), 5 * 1234, np.uint16))
    for name in ("1305031102.175304", "1305031102.211214"):
        write_png(root / "rgb" / f"{name}.png", np.zeros((480, 640, 3), np.uint8))
    seq = read_tum_sequence(root)
    assert len(seq) == 2
    a, b = seq.frames
    assert (a.timestamp_ns, a.rgb_timestamp_ns) == (1_305_031_102_160_407_000, 1_305_031_102_175_304_000)
    assert (b.timestamp_ns, b.rgb_timestamp_ns) == (1_305_031_102_194_330_000, 1_305_031_102_211_214_000)
    assert a.pose_dt_ns == 1_305_031_102_160_000_000 - a.timestamp_ns  # nearest: .1600, 0.4 ms before
    assert b.pose_dt_ns == 1_305_031_102_190_000_000 - b.timestamp_ns
    np.testing.assert_allclose(a.T_world_from_cam.translation, [1.3405, 0.6266, 1.6575])
    frame = seq.load(0)
    assert np.all(frame.depth_m == np.float32(1.234)) and frame.known.all()
    # Written back, the colour images keep their own timestamps and the poses sit at the depth ones.
    write_tum_sequence(tmp_path / "copy", seq, seq.intrinsics)
    copy = read_tum_sequence(tmp_path / "copy", max_dt_s=0.02)
    assert [(c.timestamp_ns, c.rgb_timestamp_ns, c.pose_dt_ns) for c in copy.frames] == [
        (f.timestamp_ns, f.rgb_timestamp_ns, 0) for f in seq.frames]
    assert (tmp_path / "copy" / "rgb" / "1305031102.175304.png").is_file()


# --- association -----------------------------------------------------------------------------------


def make_index_sequence(root: Path, depth_ns, rgb_ns, pose_ns, pose_fn=None) -> None:
    """Index and pose files only (association does not read images)."""
    def fmt(ns):
        return f"{ns // 10**9}.{ns % 10**9:09d}"

    write_text(root / "depth.txt", [f"{fmt(t)} depth/{t}.png" for t in depth_ns])
    write_text(root / "rgb.txt", [f"{fmt(t)} rgb/{t}.png" for t in rgb_ns])
    lines = []
    for t in pose_ns:
        tr, q = pose_fn(t) if pose_fn else (np.array([t * 1e-9, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
        lines.append(fmt(t) + " " + " ".join(f"{x:.17g}" for x in (*tr, *q)))
    write_text(root / "groundtruth.txt", lines)


def test_association_by_nearest_timestamp_with_jitter(tmp_path):
    rng = np.random.default_rng(5)
    n = 120
    base = 10**12 + np.arange(n) * 33_333_333
    depth_ns = base + rng.integers(-4_000_000, 4_000_000, n)
    rgb_ns = base + 9_000_000 + rng.integers(-4_000_000, 4_000_000, n)  # colour 5–13 ms after depth
    pose_ns = np.arange(base[0] - 10**8, base[-1] + 10**8, 10_000_000) + rng.integers(-1_000_000, 1_000_000)
    gap = (pose_ns > base[40]) & (pose_ns < base[50])  # a motion-capture dropout
    pose_ns = pose_ns[~gap]
    rgb_keep = np.ones(n, bool)
    rgb_keep[[7, 80]] = False  # two colour images lost
    make_index_sequence(tmp_path, depth_ns, rgb_ns[rgb_keep], pose_ns)
    seq = read_tum_sequence(tmp_path, max_dt_s=0.02)
    # Brute force: depth i pairs with colour i (other colour images are ≥ 20 ms away) and with the pose
    # nearest in time if within 20 ms.
    want_rgb, no_rgb, no_pose = {}, 0, 0
    for i in range(n):
        if not rgb_keep[i]:
            no_rgb += 1
            continue
        dt = np.abs(pose_ns - depth_ns[i])
        if dt.min() > 20_000_000:
            no_pose += 1
            continue
        want_rgb[int(depth_ns[i])] = (int(rgb_ns[i]), int(pose_ns[np.argmin(dt)]))
    assert no_pose > 0
    assert seq.skipped == {"no_rgb": no_rgb, "no_pose": no_pose, "rgb_unused": 0}
    assert len(seq) == len(want_rgb)
    for a in seq.frames:
        rgb_t, pose_t = want_rgb[a.timestamp_ns]
        assert a.rgb_timestamp_ns == rgb_t
        assert a.pose_dt_ns == pose_t - a.timestamp_ns
        assert a.T_world_from_cam.translation[0] == pytest.approx(pose_t * 1e-9, abs=1e-9)
        assert a.depth_path == tmp_path / "depth" / f"{a.timestamp_ns}.png"


def test_association_is_one_to_one_and_greedy_by_smallest_gap(tmp_path):
    # Two depth images 8 and 3 ms before one colour image: the nearer one takes it, the other has none.
    make_index_sequence(tmp_path, [1_000_000_000, 1_005_000_000], [1_008_000_000], [1_000_000_000, 1_005_000_000])
    seq = read_tum_sequence(tmp_path)
    assert [a.timestamp_ns for a in seq.frames] == [1_005_000_000]
    assert seq.skipped == {"no_rgb": 1, "no_pose": 0, "rgb_unused": 0}
    assert read_tum_sequence(tmp_path, max_dt_s=0.001).skipped == {"no_rgb": 2, "no_pose": 0, "rgb_unused": 1}


def test_linear_pose_interpolation_matches_slerp(tmp_path):
    def pose(t):
        a = (t - 10**9) / 10**7  # 0 at the first pose, 1 at the second
        return np.array([a * 0.2, 1.0, -a]), Rotation.from_rotvec([0.0, 0.0, a * 0.8]).as_quat()

    make_index_sequence(tmp_path, [1_002_500_000], [1_002_500_000], [1_000_000_000, 1_010_000_000], pose)
    lin = read_tum_sequence(tmp_path, poses="linear").frames[0]
    np.testing.assert_allclose(lin.T_world_from_cam.translation, [0.05, 1.0, -0.25], atol=1e-12)
    np.testing.assert_allclose(lin.T_world_from_cam.rotation, Rotation.from_rotvec([0, 0, 0.2]).as_matrix(), atol=1e-12)
    nearest = read_tum_sequence(tmp_path).frames[0]
    np.testing.assert_allclose(nearest.T_world_from_cam.translation, [0.0, 1.0, 0.0], atol=1e-12)
    assert nearest.pose_dt_ns == -2_500_000 and lin.pose_dt_ns == 0
    # Outside the poses' span there is nothing to interpolate between.
    make_index_sequence(tmp_path, [1_012_000_000], [1_012_000_000], [1_000_000_000, 1_010_000_000], pose)
    assert len(read_tum_sequence(tmp_path, poses="linear")) == 0 and len(read_tum_sequence(tmp_path)) == 1


def test_bad_arguments(tmp_path):
    make_index_sequence(tmp_path, [10**9], [10**9], [10**9])
    with pytest.raises(RangeError, match="max_dt_s"):
        read_tum_sequence(tmp_path, max_dt_s=-0.1)
    with pytest.raises(RangeError, match="max_dt_s"):
        read_tum_sequence(tmp_path, max_dt_s=float("nan"))
    with pytest.raises(UnknownMethodError, match="poses"):
        read_tum_sequence(tmp_path, poses="cubic")
    with pytest.raises(LogFormatError, match="not a directory"):
        read_tum_sequence(tmp_path / "nope")


# --- bad files: each names the file and line -------------------------------------------------------


@pytest.mark.parametrize("name", ["rgb.txt", "depth.txt", "groundtruth.txt"])
def test_missing_index_file(written, name):
    root, _ = written
    (root / name).unlink()
    with pytest.raises(LogFormatError, match=rf"{name}: missing file"):
        read_tum_sequence(root)


def corrupt_line(path: Path, data_line: int, new: str) -> int:
    """Replace the ``data_line``-th non-comment line; return its 1-based line number."""
    lines = path.read_text().splitlines()
    idx = [i for i, l in enumerate(lines) if not l.startswith("#")][data_line]
    lines[idx] = new(lines[idx]) if callable(new) else new
    path.write_text("\n".join(lines) + "\n")
    return idx + 1


@pytest.mark.parametrize(
    "name, new, message",
    [
        ("rgb.txt", lambda l: l + " extra", "expected 2 fields, got 3"),
        ("depth.txt", lambda l: "1e9 " + l.split()[1], "malformed timestamp"),
        ("depth.txt", lambda l: "-1.5 " + l.split()[1], "malformed timestamp"),
        ("rgb.txt", lambda l: "1.000000 " + l.split()[1], "does not increase"),  # unsorted
        ("groundtruth.txt", lambda l: " ".join(l.split()[:4] + ["nan"] + l.split()[5:]), "NaN or inf"),
        ("groundtruth.txt", lambda l: " ".join(l.split()[:4] + ["0.5", "0.5", "0.5", "0.1"]), "quaternion norm"),
        ("groundtruth.txt", lambda l: " ".join(l.split()[:7]), "expected 8 fields, got 7"),
        ("groundtruth.txt", lambda l: l.replace(l.split()[2], "abc", 1), "must be numbers"),
        ("depth.txt", lambda l: l.split()[0] + " /etc/passwd", "relative"),
    ],
)
def test_malformed_text_lines(written, name, new, message):
    root, _ = written
    lineno = corrupt_line(root / name, 2, new)
    with pytest.raises(LogFormatError, match=rf"{name}, line {lineno}: .*{message}"):
        read_tum_sequence(root)


def test_duplicate_timestamp_is_rejected(written):
    root, _ = written
    lines = (root / "groundtruth.txt").read_text().splitlines()
    lines.insert(5, lines[4])
    (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(LogFormatError, match=r"groundtruth.txt, line 6: .*does not increase"):
        read_tum_sequence(root)


def index_of(root: Path, name: str, i: int) -> tuple[Path, int]:
    lines = (root / name).read_text().splitlines()
    idx = [k for k, l in enumerate(lines) if not l.startswith("#")][i]
    return root / lines[idx].split()[1], idx + 1


def test_missing_image_names_file_and_index_line(written):
    root, _ = written
    path, lineno = index_of(root, "depth.txt", 3)
    path.unlink()
    seq = read_tum_sequence(root)  # images are read lazily
    seq.load(2)
    with pytest.raises(LogFormatError, match=rf"{path}.*depth.txt line {lineno}.*missing file"):
        seq.load(3)


@pytest.mark.parametrize("cut", [0.5, 0.99])
def test_truncated_png(written, cut):
    root, _ = written
    path, lineno = index_of(root, "rgb.txt", 1)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * cut)])
    with pytest.raises(LogFormatError, match=rf"{path} \(rgb.txt line {lineno}\): unreadable, truncated or corrupt PNG"):
        read_tum_sequence(root).load(1)


def test_corrupt_png_body_and_non_png(written):
    root, _ = written
    path, _ = index_of(root, "depth.txt", 0)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # CRC mismatch in the image data
    path.write_bytes(bytes(data))
    with pytest.raises(LogFormatError, match="corrupt PNG"):
        read_tum_sequence(root).load(0)
    path.write_bytes(b"GIF89a not a png")
    with pytest.raises(LogFormatError, match="not a PNG"):
        read_tum_sequence(root).load(0)


@pytest.mark.parametrize(
    "kind, img, message",
    [
        ("depth", np.zeros((H, W), np.uint8), "16-bit depth PNG, got dtype uint8"),
        ("depth", np.zeros((H, W, 3), np.uint16), "single-channel 16-bit"),
        ("depth", np.zeros((H + 1, W), np.uint16), "expected 16×20 from the intrinsics"),
        ("rgb", np.zeros((H, W, 3), np.uint16), "8-bit 3-channel colour PNG, got dtype uint16"),
        ("rgb", np.zeros((H, W), np.uint8), "8-bit 3-channel"),
        ("rgb", np.zeros((H, W, 4), np.uint8), "8-bit 3-channel"),
        ("rgb", np.zeros((H, W + 2, 3), np.uint8), "expected 16×20 from the intrinsics"),
    ],
)
def test_wrong_png_dtype_channels_or_size(written, kind, img, message):
    root, _ = written
    path, lineno = index_of(root, f"{kind}.txt", 0)
    write_png(path, img)
    with pytest.raises(LogFormatError, match=rf"{path} \({kind}.txt line {lineno}\): .*{message}"):
        read_tum_sequence(root).load(0)


@pytest.mark.parametrize(
    "text, message",
    [
        ("{not json", r"calibration.json, line 1: invalid JSON"),
        ('{"sensor": "kinect"}', "invalid calibration"),
        ('{"format": "rgbd-envmap-session", "version": 1}', "expected format 'rgbd-envmap-tum'"),
        ("[1, 2]", "expected a JSON object"),
    ],
)
def test_bad_calibration_json(written, text, message):
    root, _ = written
    (root / "calibration.json").write_text(text)
    with pytest.raises(LogFormatError, match=message):
        read_tum_sequence(root)


def test_calibration_must_be_registered(written):
    root, _ = written
    d = json.loads((root / "calibration.json").read_text())
    d["depth"]["fx"] = 17.0
    (root / "calibration.json").write_text(json.dumps(d))
    with pytest.raises(LogFormatError, match="registered"):
        read_tum_sequence(root)
    d["depth"]["fx"] = d["colour"]["fx"]
    d["T_colour_from_depth"][0][3] = 0.025
    (root / "calibration.json").write_text(json.dumps(d))
    with pytest.raises(LogFormatError, match="identity"):
        read_tum_sequence(root)


# --- writer errors ---------------------------------------------------------------------------------


def test_writer_rejects_bad_frames(tmp_path):
    rng = np.random.default_rng(4)
    good = random_frame(rng, 10**9)

    class Loose:  # a duck-typed frame without TumFrame's own validation
        def __init__(self, **kw):
            self.__dict__.update({"timestamp_ns": 2 * 10**9, "rgb": good.rgb, "depth_m": good.depth_m, "known": good.known,
                                  "T_world_from_cam": good.T_world_from_cam} | kw)

    cases = [
        (Loose(rgb=good.rgb.astype(np.float32)), DTypeError, r"frames\[1\].rgb"),
        (Loose(rgb=good.rgb[:, :-1]), ShapeError, r"frames\[1\].rgb"),
        (Loose(depth_m=np.ones((H, W), np.int32)), DTypeError, r"frames\[1\].depth_m"),
        (Loose(known=good.known.astype(np.uint8)), DTypeError, r"frames\[1\].known"),
        (Loose(depth_m=np.full((H, W), 14.0, np.float32)), RangeError, r"frames\[1\].depth_m.*13.107"),
        (Loose(depth_m=np.full((H, W), np.nan, np.float32)), RangeError, r"frames\[1\].depth_m.*NaN"),
        (Loose(depth_m=np.zeros((H, W), np.float32)), RangeError, r"frames\[1\].depth_m"),
        (Loose(timestamp_ns=10**9), InvalidInputError, r"frames\[1\].timestamp_ns"),
        (Loose(T_world_from_cam=np.eye(4)), InvalidInputError, r"frames\[1\].T_world_from_cam"),
    ]
    for k, (bad, error, message) in enumerate(cases):
        root = tmp_path / f"s{k}"
        with pytest.raises(error, match=message):
            write_tum_sequence(root, [good, bad], INTR)
        seq = read_tum_sequence(root)  # the frames before the bad one stay readable
        assert len(seq) == 1 and np.array_equal(seq.load(0).rgb, good.rgb)


def test_writer_directory_rules(tmp_path, written):
    root, frames = written
    with pytest.raises(LogFormatError, match="not empty"):
        write_tum_sequence(root, frames[:1], INTR)
    (root / "notes.md").write_text("mine")
    write_tum_sequence(root, frames[:2], INTR, overwrite=True, calibration_json=False)
    assert (root / "notes.md").read_text() == "mine" and not (root / "calibration.json").exists()
    assert len(list((root / "depth").iterdir())) == 2
    assert read_tum_sequence(root, intrinsics=INTR).timestamps_ns.tolist() == [f.timestamp_ns for f in frames[:2]]
    with pytest.raises(InvalidInputError, match="timestamp_decimals"):
        write_tum_sequence(tmp_path / "x", frames, INTR, timestamp_decimals=3)
    with pytest.raises(InvalidInputError, match="intrinsics"):
        write_tum_sequence(tmp_path / "y", frames, (W, H))


def test_empty_sequence(tmp_path):
    assert write_tum_sequence(tmp_path / "e", [], INTR) == 0
    seq = read_tum_sequence(tmp_path / "e")
    assert len(seq) == 0 and list(seq) == [] and seq.timestamps_ns.shape == (0,)


def test_tum_frame_validates():
    rgb = np.zeros((H, W, 3), np.uint8)
    depth = np.zeros((H, W), np.float32)
    T = RigidTransform.identity()
    with pytest.raises(ShapeError, match="depth_m"):
        TumFrame(0, rgb, depth[:-1], depth > 0, T)
    with pytest.raises(DTypeError, match="rgb"):
        TumFrame(0, rgb.astype(np.float32), depth, depth > 0, T)
    with pytest.raises(InvalidInputError, match="T_world_from_cam"):
        TumFrame(0, rgb, depth, depth > 0, np.eye(4))
    f = TumFrame(0, rgb, depth.astype(np.float64), depth > 0, T)
    assert f.depth_m.dtype == np.float32 and not f.rgb.flags.writeable


# --- the benchmark's cameras, depth scale and other trajectories -----------------------------------


def test_presets_are_the_benchmarks_published_calibrations():
    """The "File Formats" page's table (fx fy cx cy d0 … d4, d in OpenCV's k1 k2 p1 p2 k3 order) and its
    depth correction factors, typed in again here."""
    published = {
        "fr1": (517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
        "fr2": (520.9, 521.0, 325.1, 249.7, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
        "fr3": (535.4, 539.2, 320.1, 247.6, (0.0, 0.0, 0.0, 0.0, 0.0)),
        "default": (525.0, 525.0, 319.5, 239.5, (0.0, 0.0, 0.0, 0.0, 0.0)),
    }
    assert set(TUM_INTRINSICS) == set(published)
    for name, (fx, fy, cx, cy, d) in published.items():
        intr = TUM_INTRINSICS[name]
        assert (intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy) == (640, 480, fx, fy, cx, cy)
        assert tuple(intr.distortion.coefficients) == d
    assert TUM_INTRINSICS["default"] == TUM_DEFAULT_INTRINSICS
    assert TUM_DEPTH_CORRECTION == {"fr1": 1.035, "fr2": 1.031, "fr3": 1.0, "default": 1.0}


@pytest.mark.parametrize("name, camera", [
    ("rgbd_dataset_freiburg1_xyz", "fr1"),
    ("rgbd_dataset_freiburg2_pioneer_360", "fr2"),
    ("rgbd_dataset_freiburg3_long_office_household_validation", "fr3"),
    ("rgbd_dataset_freiburg1_desk2", "fr1"),
    ("freiburg1_xyz", None),  # not the benchmark's folder name
    ("rgbd_dataset_freiburg4_x", None),
    ("rgbd_dataset_freiburg1_rgbd_dataset_freiburg2_x", None),  # two cameras named: ambiguous
    ("my_sequence", None),
])
def test_camera_from_folder_name(tmp_path, name, camera):
    assert tum_camera_from_name(tmp_path / name) == camera
    assert tum_camera_from_name(f"{tmp_path / name}/") == camera
    assert tum_camera_from_name(tmp_path / name / "rgbd_dataset_freiburg3_x" / "..") == camera  # ".." is resolved


def test_camera_from_name_looks_at_the_folder_not_its_parents(tmp_path, monkeypatch):
    inner = tmp_path / "rgbd_dataset_freiburg2_desk" / "copy"
    inner.mkdir(parents=True)
    assert tum_camera_from_name(inner) is None
    monkeypatch.chdir(inner.parent)
    assert tum_camera_from_name(".") == "fr2"


def test_auto_intrinsics_calibration_json_then_folder_name_then_default(tmp_path):
    fr1 = tmp_path / "rgbd_dataset_freiburg1_room"
    make_index_sequence(fr1, [10**9], [10**9], [10**9])
    seq = read_tum_sequence(fr1, intrinsics="auto")
    assert seq.intrinsics == TUM_INTRINSICS["fr1"] and seq.calibration is None
    assert seq.intrinsics_source[0] == "fr1" and "rgbd_dataset_freiburg1_room" in seq.intrinsics_source[1]
    # Without "auto" the reader keeps its old default; a preset by name overrides everything.
    assert read_tum_sequence(fr1).intrinsics == TUM_DEFAULT_INTRINSICS
    assert read_tum_sequence(fr1, intrinsics="fr3").intrinsics_source == ("fr3", "given by name")
    other = tmp_path / "seq"
    make_index_sequence(other, [10**9], [10**9], [10**9])
    seq = read_tum_sequence(other, intrinsics="auto")
    assert seq.intrinsics == TUM_DEFAULT_INTRINSICS and seq.intrinsics_source[0] == "default"
    assert "names no freiburg camera" in seq.intrinsics_source[1]
    cal = Calibration("kinect", INTR, INTR, RigidTransform.identity("colour", "depth"), 30.0, 30.0)
    (fr1 / "calibration.json").write_text(json.dumps(cal.to_dict()))
    seq = read_tum_sequence(fr1, intrinsics="auto")
    assert seq.intrinsics == INTR and seq.intrinsics_source[0] == "calibration.json"
    with pytest.raises(UnknownMethodError, match="intrinsics"):
        read_tum_sequence(fr1, intrinsics="fr4")


def test_pipeline_calibration_without_calibration_json(tmp_path):
    """The regression of issue 21: a published sequence has no calibration.json; the pipeline still
    gets a kinect Calibration of the intrinsics in use."""
    make_index_sequence(tmp_path / "s", [10**9], [10**9], [10**9])
    seq = read_tum_sequence(tmp_path / "s", intrinsics="fr2")
    cal = seq.pipeline_calibration
    assert cal.sensor == "kinect" and cal.depth == cal.colour == TUM_INTRINSICS["fr2"]
    np.testing.assert_array_equal(cal.T_colour_from_depth.matrix, np.eye(4))
    assert (cal.depth_rate_hz, cal.colour_rate_hz) == (30.0, 30.0)


def test_depth_scale_and_correction(written):
    root, frames = written
    base = read_tum_sequence(root).load(0).depth_m
    png = cv2.imread(str(read_tum_sequence(root).frames[0].depth_path), cv2.IMREAD_UNCHANGED)
    seq = read_tum_sequence(root, depth_scale=1000.0)
    assert seq.depth_scale == 1000.0
    np.testing.assert_array_equal(seq.load(0).depth_m, (png / 1000.0).astype(np.float32))
    np.testing.assert_array_equal(base, (png / 5000.0).astype(np.float32))  # the default is unchanged
    seq = read_tum_sequence(root, depth_correction=TUM_DEPTH_CORRECTION["fr1"])
    np.testing.assert_allclose(seq.load(0).depth_m, png / 5000.0 * 1.035, rtol=1e-7)
    assert np.array_equal(seq.load(0).known, frames[0].known)
    for bad in (0.0, -5000.0, float("nan"), float("inf"), "5000", True):
        with pytest.raises((RangeError, DTypeError), match="depth_scale"):
            read_tum_sequence(root, depth_scale=bad)
        with pytest.raises((RangeError, DTypeError), match="depth_correction"):
            read_tum_sequence(root, depth_correction=bad)


def test_another_trajectory_file_replaces_groundtruth(written, tmp_path):
    """An estimated trajectory in TUM format, read by the same parser: its poses are used, its gaps
    skip frames, and its errors name its own file."""
    root, frames = written
    est = tmp_path / "estimate.txt"
    lines = ["# an estimate, offset by 1 m in x, covering the first three frames"]
    for f in frames[:3]:
        T = f.T_world_from_cam
        ns = f.timestamp_ns
        lines.append(f"{ns // 10**9}.{ns % 10**9:09d} " + " ".join(f"{x:.17g}" for x in (*(T.translation + [1.0, 0, 0]), *T.quaternion_xyzw())))
    est.write_text("\n".join(lines) + "\n")
    seq = read_tum_sequence(root, trajectory=est)
    assert seq.trajectory == est and len(seq) == 3 and seq.skipped["no_pose"] == 2
    for f, a in zip(frames, seq.frames):
        np.testing.assert_allclose(a.T_world_from_cam.translation, f.T_world_from_cam.translation + [1.0, 0, 0], atol=1e-12)
    (root / "groundtruth.txt").unlink()
    assert len(read_tum_sequence(root, trajectory=est)) == 3  # groundtruth.txt is not needed then
    with pytest.raises(LogFormatError, match="nope.txt: missing file"):
        read_tum_sequence(root, trajectory=tmp_path / "nope.txt")
    est.write_text(est.read_text() + "not a pose\n")
    with pytest.raises(LogFormatError, match=r"estimate.txt, line 5: expected 8 fields"):
        read_tum_sequence(root, trajectory=est)


def test_trajectory_pose_lookup(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("# t tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n1.1 1 0 0 0 0 0 1\n")
    track = TumTrajectory(path)
    assert len(track) == 2 and track.timestamps_ns.tolist() == [10**9, 11 * 10**8]
    T, dt = track.pose_at(1_040_000_000, 50_000_000)
    assert dt == -40_000_000 and T.translation[0] == 0.0
    T, dt = track.pose_at(1_040_000_000, 100_000_000, "linear")
    assert dt == 0 and T.translation[0] == pytest.approx(0.4)
    assert track.pose_at(1_300_000_000, 50_000_000) is None
    with pytest.raises(UnknownMethodError):
        track.pose_at(10**9, 0, "cubic")
