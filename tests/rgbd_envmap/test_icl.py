"""Tests for rgbd_envmap.icl: the TUM-compatible ICL-NUIM layout, written here by hand (frame numbers
as timestamps, ``t_depth depth/N.png t_rgb rgb/N.png`` associations, one ``*.gt.freiburg``), its
published intrinsics (fy < 0), and its errors (naming file and line)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rgbd_envmap.errors import InvalidInputError, LogFormatError, RangeError, UnknownMethodError
from rgbd_envmap.icl import ICL_NUIM_INTRINSICS, icl_nuim_trajectory, is_icl_nuim_sequence, read_icl_nuim_sequence
from rgbd_envmap.types import Intrinsics

W, H = 16, 12
SMALL = Intrinsics(W, H, 12.0, -12.0, 7.5, 5.5)


def write_png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", img)
    assert ok
    path.write_bytes(buf.tobytes())


def make_icl(root: Path, n: int = 4, *, rgb_first: bool = False, gt_frames=None) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    depths = []
    lines, gt = ["# timestamp depth timestamp rgb"], []
    for k in range(n):
        d = rng.integers(1000, 20000, (H, W)).astype(np.uint16)
        d[0, 0] = 0
        depths.append(d)
        write_png(root / "depth" / f"{k}.png", d)
        write_png(root / "rgb" / f"{k}.png", rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        lines.append(f"{k} rgb/{k}.png {k} depth/{k}.png" if rgb_first else f"{k} depth/{k}.png {k} rgb/{k}.png")
    for k in (range(n) if gt_frames is None else gt_frames):
        gt.append(f"{k} {0.1 * k} 0.0 -2.25 0 0 0 1")
    (root / "associations.txt").write_text("\n".join(lines) + "\n")
    (root / "livingRoom0.gt.freiburg").write_text("\n".join(gt) + "\n")
    return depths


def test_published_intrinsics_are_signed():
    i = ICL_NUIM_INTRINSICS
    assert (i.width, i.height, i.fx, i.fy, i.cx, i.cy) == (640, 480, 481.20, -480.00, 319.5, 239.5)
    assert i.distortion.is_zero


def test_layout_is_recognised_and_read(tmp_path):
    root = tmp_path / "living_room_traj0_frei_png"
    depths = make_icl(root)
    assert is_icl_nuim_sequence(root) and not is_icl_nuim_sequence(tmp_path)
    seq = read_icl_nuim_sequence(root, intrinsics=SMALL)
    assert len(seq) == 4 and seq.trajectory == root / "livingRoom0.gt.freiburg"
    assert seq.timestamps_ns.tolist() == [k * 10**9 for k in range(4)]
    assert seq.intrinsics_source == ("given", "given by the caller") and seq.pipeline_calibration.depth == SMALL
    f = seq.load(2)
    np.testing.assert_array_equal(f.depth_m, (depths[2] / 5000.0).astype(np.float32))
    assert not f.known[0, 0] and f.known.sum() == W * H - 1
    np.testing.assert_allclose(f.T_world_from_cam.translation, [0.2, 0.0, -2.25])
    assert read_icl_nuim_sequence(root).intrinsics == ICL_NUIM_INTRINSICS
    assert read_icl_nuim_sequence(root).intrinsics_source[0] == "icl-nuim"
    np.testing.assert_array_equal(read_icl_nuim_sequence(root, intrinsics=SMALL, depth_scale=1000.0).load(0).depth_m,
                                  (depths[0] / 1000.0).astype(np.float32))


def test_colour_first_associations_are_read_by_their_folders(tmp_path):
    make_icl(tmp_path / "a", rgb_first=True)
    seq = read_icl_nuim_sequence(tmp_path / "a", intrinsics=SMALL)
    assert [a.depth_path.parent.name for a in seq.frames] == ["depth"] * 4
    assert [a.rgb_path.parent.name for a in seq.frames] == ["rgb"] * 4


def test_frames_without_a_pose_are_skipped_and_counted(tmp_path):
    make_icl(tmp_path / "a", gt_frames=[0, 1, 3])
    seq = read_icl_nuim_sequence(tmp_path / "a", intrinsics=SMALL)
    assert len(seq) == 3 and seq.skipped["no_pose"] == 1
    assert [a.timestamp_ns // 10**9 for a in seq.frames] == [0, 1, 3]


def test_another_trajectory(tmp_path):
    make_icl(tmp_path / "a")
    est = tmp_path / "est.txt"
    est.write_text("0 5 5 5 0 0 0 1\n1 5 5 5 0 0 0 1\n")
    seq = read_icl_nuim_sequence(tmp_path / "a", intrinsics=SMALL, trajectory=est)
    assert len(seq) == 2 and seq.trajectory == est
    np.testing.assert_array_equal(seq.frames[0].T_world_from_cam.translation, [5, 5, 5])


def test_errors_name_the_file_and_line(tmp_path):
    root = tmp_path / "a"
    make_icl(root)
    (root / "office.gt.freiburg").write_text("0 0 0 0 0 0 0 1\n")
    with pytest.raises(LogFormatError, match=r"expected one \*\.gt\.freiburg trajectory file, found 2"):
        read_icl_nuim_sequence(root)
    (root / "office.gt.freiburg").unlink()
    assert icl_nuim_trajectory(root).name == "livingRoom0.gt.freiburg"
    lines = (root / "associations.txt").read_text().splitlines()
    for bad, message in ((lines[2] + " extra", r"associations.txt, line 3: expected 4 fields, got 5"),
                         ("1 depth/1.png x rgb/1.png", r"associations.txt, line 3: malformed timestamp"),
                         ("1 /etc/passwd 1 rgb/1.png", r"associations.txt, line 3: image path must be relative"),
                         ("0 depth/0.png 0 rgb/0.png", r"associations.txt, line 3: timestamp 0 does not increase")):
        (root / "associations.txt").write_text("\n".join(lines[:2] + [bad] + lines[3:]) + "\n")
        with pytest.raises(LogFormatError, match=message):
            read_icl_nuim_sequence(root)
    (root / "associations.txt").write_text("\n".join(lines) + "\n")
    (root / "depth" / "1.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    with pytest.raises(LogFormatError, match=r"1.png \(associations.txt line 3\)"):
        read_icl_nuim_sequence(root, intrinsics=SMALL).load(1)
    with pytest.raises(LogFormatError, match=r"expected 13×16 from the intrinsics, got \(12, 16\)"):
        read_icl_nuim_sequence(root, intrinsics=Intrinsics(W, H + 1, 12.0, -12.0, 7.5, 5.5)).load(0)
    with pytest.raises(LogFormatError, match="not a directory"):
        read_icl_nuim_sequence(tmp_path / "nope")
    with pytest.raises(RangeError, match="depth_scale"):
        read_icl_nuim_sequence(root, depth_scale=0)
    with pytest.raises(UnknownMethodError, match="poses"):
        read_icl_nuim_sequence(root, poses="spline")
    with pytest.raises(InvalidInputError, match="intrinsics"):
        read_icl_nuim_sequence(root, intrinsics="fr1")
    (root / "livingRoom0.gt.freiburg").unlink()
    assert not is_icl_nuim_sequence(root)
    with pytest.raises(LogFormatError, match="found no"):
        read_icl_nuim_sequence(root)
