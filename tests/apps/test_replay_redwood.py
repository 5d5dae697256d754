"""Redwood folders (Open3D's layout of the Redwood / Augmented ICL-NUIM data), written here by hand
(tests/apps/dataset_writers.py: JPEG colour, millimetre depth PNGs, Open3D's camera JSON, a ``.log``
trajectory), replay end to end; the ``.log`` and camera readers agree with Open3D's own; a folder
without poses fails naming ``--poses FILE``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import rgbd_envmap
from apps.cli import main
from rgbd_envmap.config import load_yaml
from rgbd_envmap.errors import LogFormatError
from rgbd_envmap.logs import read_log_trajectory, trajectory_format
from rgbd_envmap.pipeline import PipelineConfig
from rgbd_envmap.sources.frames import detect_source_layout, open_source
from rgbd_envmap.sources.options import read_intrinsics_json
from rgbd_envmap.tum import open_trajectory
from tests.apps.dataset_writers import ORIGIN, pose_at, quaternion_xyzw, write_redwood
from tests.apps.test_replay_datasets import map_errors

SMALL = ["--em-size", "500x250", "--no-render", "--no-video", "--quiet", "--set", "kinect_em_every=2"]
#: not Open3D's PrimeSense default, so that reading camera_intrinsic.json is seen to matter
K = np.array([[590.0, 0.0, 330.0], [0.0, 588.0, 230.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def redwood(tmp_path_factory):
    return write_redwood(tmp_path_factory.mktemp("redwood") / "livingroom1", n_frames=12, K=K)


def test_a_redwood_folder_replays_with_its_camera_and_trajectory(redwood, tmp_path):
    root = redwood["root"]
    assert detect_source_layout(root).name == "Redwood"
    out = tmp_path / "run"
    assert main(["replay", str(root), "--out", str(out), "--origin", *map(str, ORIGIN), *SMALL]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["layout"] == "Redwood" and "Redwood" in info["source"] and info["depth_frames_processed"] == 6
    intr = info["intrinsics"]
    assert intr["source"] == "camera_intrinsic.json" and (intr["fx"], intr["fy"], intr["cx"], intr["cy"]) == (590, 588, 330, 230)
    assert info["depth_scale_units_per_m"] == 1000.0 and info["poses_file"].endswith("room-traj.txt")
    e = map_errors(out, redwood["raycaster"], ORIGIN)
    assert e["coverage"] > 0.1 and e["median_m"] < 0.012 and e["psnr_db"] > 20.0
    # the one-call API on the same folder: the same map, bit for bit
    result = rgbd_envmap.replay(root, load_yaml(PipelineConfig, out / "config.yaml"), origin=ORIGIN)
    with np.load(out / "envmap.npz") as z:
        np.testing.assert_array_equal(result.envmap.radiance, z["radiance"])
        np.testing.assert_array_equal(result.envmap.valid, z["valid"])


def test_the_camera_matters(redwood, tmp_path):
    """The PrimeSense default instead of the folder's camera puts the map off."""
    good, bad = tmp_path / "good", tmp_path / "bad"
    for out, extra in ((good, []), (bad, ["--intrinsics", "primesense"])):
        assert main(["replay", str(redwood["root"]), "--out", str(out), "--origin", *map(str, ORIGIN), *SMALL, *extra]) == 0
    assert json.loads((bad / "run.json").read_text())["intrinsics"]["reason"] == "--intrinsics primesense"
    g, b = map_errors(good, redwood["raycaster"], ORIGIN), map_errors(bad, redwood["raycaster"], ORIGIN)
    assert b["p90_m"] > 1.5 * g["p90_m"]


def test_log_and_camera_files_read_as_open3d_reads_them(redwood, tmp_path):
    o3d = pytest.importorskip("open3d")
    root = redwood["root"]
    path = root / "room-traj.txt"
    assert trajectory_format(path) == "log"
    ids, mats = read_log_trajectory(path)
    theirs = o3d.io.read_pinhole_camera_trajectory(str(_as_log(path, tmp_path)))
    assert list(ids) == list(range(12)) and len(theirs.parameters) == 12
    for m, p in zip(mats, theirs.parameters):  # Open3D keeps the inverse: world to camera
        np.testing.assert_allclose(np.linalg.inv(p.extrinsic), m, atol=1e-7)
    R, t = pose_at(3 * 3 / 30.0)
    np.testing.assert_allclose(mats[3][:3, :3], R, atol=1e-7)
    np.testing.assert_allclose(mats[3][:3, 3], t, atol=1e-8)
    ours = read_intrinsics_json(root / "camera_intrinsic.json")
    cam = o3d.io.read_pinhole_camera_intrinsic(str(root / "camera_intrinsic.json"))
    np.testing.assert_allclose(cam.intrinsic_matrix, ours.K)
    written = tmp_path / "o3d_cam.json"  # and a file Open3D writes
    o3d.io.write_pinhole_camera_intrinsic(str(written), o3d.camera.PinholeCameraIntrinsic(320, 240, 300.5, 301.5, 160.25, 119.75))
    back = read_intrinsics_json(written)
    assert (back.width, back.height, back.fx, back.fy, back.cx, back.cy) == (320, 240, 300.5, 301.5, 160.25, 119.75)


def _as_log(path, tmp_path):
    """Open3D tells the format by the extension: the same bytes under a .log name."""
    copy = tmp_path / "traj.log"
    copy.write_bytes(path.read_bytes())
    return copy


def test_malformed_log_files_name_the_line(tmp_path):
    bad = tmp_path / "t.log"
    bad.write_text("0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n1 1 2\n1 0 0 0\n0 1 0 0\n")
    with pytest.raises(LogFormatError, match="line 8: truncated"):
        read_log_trajectory(bad)
    bad.write_text("0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n0 0 1\n2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(LogFormatError, match="lines 7-9: not a rotation"):
        read_log_trajectory(bad)
    bad.write_text("0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(LogFormatError, match="line 6: frame 0 repeats the block at line 1"):
        read_log_trajectory(bad)
    bad.write_text("0 0 1\n1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(LogFormatError, match="NaN"):
        read_log_trajectory(bad)
    bad.write_text("a b c\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(LogFormatError, match="line 1: expected a metadata line"):
        read_log_trajectory(bad)
    bad.write_text("1 2 3 4 5\n")
    with pytest.raises(LogFormatError, match="line 1: not a trajectory"):
        open_trajectory(bad)
    # a rotation printed with few decimals is made orthonormal, not refused
    c, s = np.cos(0.3), np.sin(0.3)
    bad.write_text(f"0 0 1\n{c:.4f} {-s:.4f} 0 1\n{s:.4f} {c:.4f} 0 2\n0 0 1 3\n0 0 0 1\n")
    _, mats = read_log_trajectory(bad)
    r = mats[0][:3, :3]
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(r, [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-4)


def test_a_folder_without_poses_names_the_option_and_takes_a_poses_file(tmp_path, capsys):
    root = tmp_path / "scan"
    w = write_redwood(root, n_frames=6, K=np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]]), intrinsic_json=False,
                      trajectory=None)
    assert main(["replay", str(root), "--out", str(tmp_path / "none"), *SMALL]) == 1
    err = capsys.readouterr().err
    assert "no camera poses" in err and "--poses FILE" in err
    with pytest.raises(LogFormatError, match="poses"):
        rgbd_envmap.replay(root)
    # the same poses in TUM format, at frame / 30 s, and as .log: the same map
    tum = tmp_path / "poses.txt"
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for k in range(6):
        R, t = pose_at(k / 30.0 * 3.0)
        lines.append(f"{k / 30.0:.6f} " + " ".join(f"{x:.9f}" for x in (*t, *quaternion_xyzw(R))))
    tum.write_text("\n".join(lines) + "\n")
    log = tmp_path / "poses.log"
    log.write_text("".join(w["blocks"]))
    maps = {}
    for name, poses in (("tum", tum), ("log", log)):
        out = tmp_path / name
        assert main(["replay", str(root), "--out", str(out), "--origin", *map(str, ORIGIN), *SMALL, "--poses", str(poses)]) == 0
        info = json.loads((out / "run.json").read_text())
        assert info["intrinsics"]["source"] == "primesense" and info["poses_file"] == str(poses)
        assert info["depth_frames_processed"] == 3
        with np.load(out / "envmap.npz") as z:
            maps[name] = z["valid"], z["depth_m"]
    assert (maps["tum"][0] ^ maps["log"][0]).sum() <= 0.001 * maps["log"][0].sum()
    both = maps["tum"][0] & maps["log"][0]
    assert np.percentile(np.abs(maps["tum"][1][both] - maps["log"][1][both]), 99) < 1e-3  # poses printed to 8-9 digits
    src = open_source(root, poses=log)
    assert src.layout == "Redwood" and len(src) == 6


def test_colour_and_depth_counts_must_agree_and_a_truncated_jpeg_is_skipped(redwood, tmp_path):
    import shutil

    root = tmp_path / "copy"
    shutil.copytree(redwood["root"], root)
    victim = root / "colors" / "00002.jpg"
    victim.write_bytes(victim.read_bytes()[:500])
    out = tmp_path / "run"
    assert main(["replay", str(root), "--out", str(out), *SMALL]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["skipped"] == {"frame": 1} and "00002.jpg" in info["skipped_files"][0] and "frame 2" in info["skipped_files"][0]
    assert main(["replay", str(root), "--out", str(tmp_path / "strict"), "--strict", *SMALL]) == 1
    (root / "colors" / "00011.jpg").unlink()
    with pytest.raises(LogFormatError, match="11 colour images in colors/ but 12 depth images"):
        open_source(root)
