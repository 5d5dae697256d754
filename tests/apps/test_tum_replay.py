"""A TUM RGB-D sequence written by code replays end to end through the Kinect path."""

import json

import numpy as np
import pytest

from apps.cli import main
from rgbd_envmap import metrics
from rgbd_envmap.tum import read_tum_sequence, write_tum_sequence
from sim.groundtruth import render_envmap
from sim.kinect import KinectConfig, KinectSimulator
from sim.scene import load_scene
from sim.trajectory import load_trajectory

ORIGIN = (0.0, 0.0, 0.8)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    root = tmp_path_factory.mktemp("tum") / "seq"
    sim = KinectSimulator(load_scene("office_unlit"), load_trajectory("orbit_inward"), KinectConfig().with_resolution(160, 120), seed=5)
    n = write_tum_sequence(root, sim.run(1.0), sim.calibration.depth)
    assert n == 30
    return root, sim


def test_tum_sequence_replays_and_its_map_matches_the_scene(sequence, tmp_path):
    root, sim = sequence
    out = tmp_path / "run"
    assert main(["replay", str(root), "--out", str(out), "--origin", *map(str, ORIGIN), "--em-size", "500x250", "--no-render",
                 "--quiet", "--set", "kinect_em_every=3", "--set", "kinect_em_stride=1"]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["depth_frames_processed"] == 10 and "TUM" in info["source"]
    with np.load(out / "envmap.npz") as z:
        radiance, depth, valid = z["radiance"], z["depth_m"], z["valid"]
        np.testing.assert_array_equal(z["origin"], ORIGIN)
    gt = render_envmap(sim.raycaster, np.array(ORIGIN), 250, 500, 1.0)
    both = valid & gt.valid
    assert metrics.coverage_of(valid, gt.valid) > 0.2  # measured 0.33 after 1 s
    assert np.median(np.abs(depth[both] - gt.distance_m[both])) < 0.02  # metres (measured 1.1 cm)
    # colours are in the first frame's colour space (its gains are 1 at the start of a session)
    assert metrics.ws_psnr(np.clip(radiance, 0, 1), np.clip(gt.radiance, 0, 1), both) > 17.0  # measured 19.8 dB
    assert "Warp + merge depth (Kinect)" in (out / "timing.csv").read_text()


def test_default_origin_is_one_metre_in_front_of_the_first_camera(sequence, tmp_path):
    root, _ = sequence
    out = tmp_path / "run"
    assert main(["replay", str(root), "--out", str(out), "--em-size", "200x100", "--no-render", "--no-video", "--quiet"]) == 0
    first = read_tum_sequence(root).load(0).T_world_from_cam
    with np.load(out / "envmap.npz") as z:
        np.testing.assert_allclose(z["origin"], first.translation + first.rotation[:, 2], atol=1e-12)


def test_a_frame_with_a_broken_png_is_skipped_and_counted(sequence, tmp_path):
    import shutil

    root, _ = sequence
    copy = tmp_path / "seq"
    shutil.copytree(root, copy)
    victim = sorted((copy / "depth").glob("*.png"))[4]
    victim.write_bytes(victim.read_bytes()[:60])
    out = tmp_path / "run"
    assert main(["replay", str(copy), "--out", str(out), "--em-size", "200x100", "--no-render", "--no-video", "--quiet"]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["skipped"].get("frame") == 1 and victim.name in info["skipped_files"][0]
    assert main(["replay", str(copy), "--out", str(tmp_path / "strict"), "--strict", "--em-size", "200x100", "--no-render", "--quiet"]) == 1
