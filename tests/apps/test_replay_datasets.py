"""``replay`` on the public datasets' own layouts, written here by hand (tests/apps/dataset_writers.py):

- a TUM RGB-D sequence as the benchmark ships it (no calibration.json) — the regression test of
  issue 21, where this ended in ``AttributeError: 'NoneType' object has no attribute 'sensor'``;
- an ICL-NUIM sequence in its TUM-compatible layout, whose camera has fy < 0;
- folders that are neither, and options that do not fit the layout.

The maps are checked against the room's true map (ray-cast from the same origin).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from apps.cli import main
from rgbd_envmap.sources.frames import SOURCE_LAYOUTS, SourceLayout, detect_source_layout
from rgbd_envmap import metrics
from rgbd_envmap.errors import LogFormatError
from rgbd_envmap.tum import TUM_INTRINSICS
from sim.groundtruth import render_envmap
from tests.apps.dataset_writers import ORIGIN, write_icl_nuim, write_tum_published

EM = ["--em-size", "500x250", "--no-render", "--no-video", "--quiet"]


def replay(seq, out, *extra) -> int:
    return main(["replay", str(seq), "--out", str(out), *EM, *extra])


def map_errors(out, raycaster, origin) -> dict:
    with np.load(out / "envmap.npz") as z:
        radiance, depth, valid = z["radiance"], z["depth_m"], z["valid"]
        np.testing.assert_allclose(z["origin"], origin, atol=1e-12)
    gt = render_envmap(raycaster, np.asarray(origin), 250, 500, 0.0)
    both = valid & gt.valid
    err = np.abs(depth[both] - gt.distance_m[both])
    return {"coverage": metrics.coverage_of(valid, gt.valid), "median_m": float(np.median(err)),
            "p90_m": float(np.percentile(err, 90)),
            "psnr_db": metrics.ws_psnr(np.clip(radiance, 0, 1), np.clip(gt.radiance, 0, 1), both)}


@pytest.fixture(scope="module")
def tum(tmp_path_factory):
    """24 frames (0.8 s) of a freiburg1 sequence: rendered with fr1's published camera, distortion
    included, in a folder named as the benchmark names it."""
    fr1 = TUM_INTRINSICS["fr1"]
    return write_tum_published(tmp_path_factory.mktemp("tum") / "rgbd_dataset_freiburg1_room", fr1.K,
                               fr1.distortion.coefficients, n_frames=24)


@pytest.fixture(scope="module")
def tum_run(tum, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "fr1"
    assert replay(tum["root"], out, "--origin", *map(str, ORIGIN), "--set", "kinect_em_every=3") == 0
    return out


def test_published_tum_sequence_replays_with_the_camera_its_name_names(tum, tum_run):
    """The regression test of issue 21: no calibration.json, unsynchronised rgb / depth / poses; the
    replay builds a map, with freiburg1's calibration found from the folder name and said in run.json."""
    info = json.loads((tum_run / "run.json").read_text())
    assert info["layout"] == "TUM RGB-D" and "TUM" in info["source"]
    assert info["depth_frames_processed"] == 8 and info["skipped"] == {}
    intr = info["intrinsics"]
    assert intr["source"] == "fr1" and "rgbd_dataset_freiburg1_room" in intr["reason"] and "no calibration.json" in intr["reason"]
    assert (intr["fx"], intr["fy"], intr["cx"], intr["cy"]) == (517.3, 516.5, 318.6, 255.3)
    assert intr["distortion"] == {"k1": 0.2624, "k2": -0.9531, "p1": -0.0054, "p2": 0.0026, "k3": 1.1633}
    assert info["depth_scale_units_per_m"] == 5000.0 and info["depth_correction"] == 1.0
    assert info["poses_file"].endswith("groundtruth.txt")
    e = map_errors(tum_run, tum["raycaster"], ORIGIN)
    assert e["coverage"] > 0.11  # measured 0.137 after 0.8 s
    assert e["median_m"] < 0.012 and e["p90_m"] < 0.035  # metres (measured 8.2 mm, 22 mm)
    assert e["psnr_db"] > 20.0  # measured 22.5 dB
    assert "Warp + merge depth (Kinect)" in (tum_run / "timing.csv").read_text()


def test_the_calibration_matters(tum, tum_run, tmp_path):
    """The same frames with the ROS default camera (no distortion, another principal point): the map
    lands off (p90 error 108 mm against 22 mm), so the preset is really in use."""
    out = tmp_path / "default"
    assert replay(tum["root"], out, "--origin", *map(str, ORIGIN), "--set", "kinect_em_every=3", "--intrinsics", "default") == 0
    info = json.loads((out / "run.json").read_text())
    assert info["intrinsics"]["source"] == "default" and info["intrinsics"]["reason"] == "--intrinsics default"
    good, bad = map_errors(tum_run, tum["raycaster"], ORIGIN), map_errors(out, tum["raycaster"], ORIGIN)
    assert bad["p90_m"] > 2.5 * good["p90_m"] and bad["psnr_db"] < good["psnr_db"] - 1.5


def test_a_folder_named_otherwise_takes_the_default_camera_and_says_why(tum, tmp_path):
    seq = tmp_path / "my_recording"
    os.symlink(tum["root"], seq)
    out = tmp_path / "run"
    assert replay(seq, out, "--set", "kinect_em_every=12") == 0
    intr = json.loads((out / "run.json").read_text())["intrinsics"]
    assert intr["source"] == "default" and (intr["fx"], intr["cx"], intr["cy"]) == (525.0, 319.5, 239.5)
    assert intr["reason"] == "no calibration.json and the folder name names no freiburg camera"


def test_intrinsics_file_poses_file_and_depth_correction(tum, tmp_path):
    """--intrinsics FILE (the Intrinsics dict), --poses (an estimated trajectory: here the first
    0.4 s of the ground truth, so the later frames have no pose and are counted), and
    --tum-depth-correction (freiburg1's 1.035: the camera the folder name names)."""
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(TUM_INTRINSICS["fr1"].to_dict()))
    est = tmp_path / "estimate.txt"
    est.write_text("\n".join(tum["gt_lines"][:3 + 40]) + "\n")  # header + 40 poses at 100 Hz
    out = tmp_path / "run"
    assert replay(tum["root"], out, "--intrinsics", str(cam), "--poses", str(est), "--tum-depth-correction",
                  "--depth-scale", "5000", "--set", "kinect_em_every=3") == 0
    info = json.loads((out / "run.json").read_text())
    assert info["intrinsics"]["source"] == str(cam) and info["intrinsics"]["reason"] == "--intrinsics FILE"
    assert info["poses_file"] == str(est) and info["depth_correction"] == 1.035 and info["depth_correction_camera"] == "fr1"
    depth_t = [float(l.split()[0]) for l in (tum["root"] / "depth.txt").read_text().splitlines() if not l.startswith("#")]
    pose_t = [float(l.split()[0]) for l in tum["gt_lines"][3:3 + 40]]
    with_pose = sum(min(abs(t - p) for p in pose_t) <= 0.02 for t in depth_t)  # the association window
    assert 10 < with_pose < 16  # measured 13
    assert info["skipped"]["association_no_pose"] == 24 - with_pose and info["depth_packets"] == with_pose
    # the correction needs to know the camera: from the preset, else from the folder name
    unnamed = tmp_path / "recording"
    os.symlink(tum["root"], unnamed)
    assert replay(unnamed, tmp_path / "x", "--intrinsics", "default", "--tum-depth-correction") == 2
    cam.write_text('{"width": 640, "fx": 500}')
    assert replay(tum["root"], tmp_path / "y", "--intrinsics", str(cam)) == 1  # a malformed file: data
    assert replay(tum["root"], tmp_path / "z", "--intrinsics", "fr9") == 2


def test_a_sequence_without_groundtruth_needs_poses(tum, tmp_path, capsys):
    seq = tmp_path / "rgbd_dataset_freiburg1_room_validation"
    seq.mkdir()
    for name in ("rgb", "depth", "rgb.txt", "depth.txt"):
        os.symlink(tum["root"] / name, seq / name)
    assert replay(seq, tmp_path / "run") == 1
    err = capsys.readouterr().err
    assert "groundtruth.txt: missing file" in err and "--poses FILE" in err


# --- ICL-NUIM: fy < 0 --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def icl(tmp_path_factory):
    root = tmp_path_factory.mktemp("icl")
    return write_icl_nuim(root / "living_room_traj0_frei_png", n_frames=12), write_icl_nuim(root / "flipped", n_frames=12, flip=True)


def test_icl_nuim_replays_with_its_signed_camera_and_matches_the_flipped_frames(icl, tmp_path):
    """The ICL layout with the dataset's camera (fy = −480) against the same frames upside down with
    fy = +480 (--intrinsics FILE): the same poses, so the same map (the merged frame is used at full
    resolution: with the default stride 2 the flipped image would keep the other rows). Both match the
    room's true map."""
    seq, flipped = icl
    cam = tmp_path / "flipped.json"
    cam.write_text(json.dumps({"width": 640, "height": 480, "fx": 481.2, "fy": 480.0, "cx": 319.5, "cy": 239.5}))
    runs = {}
    for name, root, extra in (("icl", seq["root"], []), ("flipped", flipped["root"], ["--intrinsics", str(cam)])):
        runs[name] = tmp_path / name
        assert replay(root, runs[name], "--set", "kinect_em_every=2", "--set", "kinect_em_stride=1", *extra) == 0
    info = json.loads((runs["icl"] / "run.json").read_text())
    assert info["layout"] == "ICL-NUIM" and "ICL-NUIM" in info["source"] and info["depth_frames_processed"] == 6
    assert info["intrinsics"]["source"] == "icl-nuim" and (info["intrinsics"]["fx"], info["intrinsics"]["fy"]) == (481.2, -480.0)
    assert info["poses_file"].endswith("livingRoom0.gt.freiburg")
    origin = info["em_origin"]
    with np.load(runs["icl"] / "envmap.npz") as a, np.load(runs["flipped"] / "envmap.npz") as b:
        np.testing.assert_array_equal(a["origin"], b["origin"])
        va, vb = a["valid"], b["valid"]
        assert (va ^ vb).sum() <= 0.001 * (va | vb).sum()  # measured 0
        both = va & vb
        d = np.abs(a["depth_m"][both] - b["depth_m"][both])
        r = np.abs(a["radiance"][both] - b["radiance"][both])
        assert np.percentile(d, 99) < 1e-3 and np.percentile(r, 99) < 1e-3  # measured 5e-5 m, 7e-5
    for name, s in (("icl", seq), ("flipped", flipped)):
        e = map_errors(runs[name], s["raycaster"], origin)
        assert e["coverage"] > 0.2 and e["median_m"] < 0.012 and e["psnr_db"] > 22.0  # measured 0.28, 5.9 mm, 25.9 dB


# --- layouts -------------------------------------------------------------------------------------------


def test_an_unknown_folder_fails_with_the_layouts_and_the_files_found(tmp_path, capsys):
    (tmp_path / "images").mkdir()
    (tmp_path / "poses.csv").write_text("t,x\n")
    assert replay(tmp_path, tmp_path / "out") == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "calibration.json: missing file" not in err
    for layout in SOURCE_LAYOUTS:
        assert layout.name in err and layout.files in err
    assert "found images/, poses.csv" in err
    assert replay(tmp_path / "nothing_here", tmp_path / "out") == 1
    assert "not a folder" in capsys.readouterr().err
    assert replay(tmp_path / "images", tmp_path / "out") == 1
    assert "found nothing (empty folder)" in capsys.readouterr().err
    (tmp_path / "notes.txt").write_text("hello")
    assert replay(tmp_path / "notes.txt", tmp_path / "out") == 1  # a file that is no .bag
    assert "not a folder" in capsys.readouterr().err


def test_layouts_are_detected_in_table_order_and_the_table_extends(icl, tum, tmp_path):
    assert detect_source_layout(tum["root"]).name == "TUM RGB-D"
    assert detect_source_layout(icl[0]["root"]).name == "ICL-NUIM"
    (tmp_path / "calibration.json").write_text("{}")
    assert detect_source_layout(tmp_path).name == "session log"
    other = tmp_path / "phone"
    other.mkdir()
    (other / "odometry.csv").write_text("")
    with pytest.raises(LogFormatError, match="not a known recording layout"):
        detect_source_layout(other)
    extra = SourceLayout("Stray Scanner", "odometry.csv + rgb.mp4", lambda p: (p / "odometry.csv").is_file(),
                         lambda path, options: None)
    assert detect_source_layout(other, (*SOURCE_LAYOUTS, extra)) is extra


def test_sequence_options_do_not_apply_to_a_session_log(tmp_path, capsys):
    (tmp_path / "calibration.json").write_text("{}")
    assert replay(tmp_path, tmp_path / "out", "--intrinsics", "fr1", "--poses", "x.txt") == 2
    err = capsys.readouterr().err
    assert "--intrinsics, --poses: apply to TUM RGB-D, ICL-NUIM, Redwood, RealSense" in err and "session log" in err


def test_the_tum_depth_correction_applies_to_tum_only(icl, capsys, tmp_path):
    assert replay(icl[0]["root"], tmp_path / "out", "--tum-depth-correction") == 2
    err = capsys.readouterr().err
    assert "--tum-depth-correction: applies to TUM RGB-D, not to a recording of the ICL-NUIM layout" in err


def test_replay_help_lists_every_layout_and_where_its_poses_come_from(capsys):
    with pytest.raises(SystemExit):
        main(["replay", "--help"])
    out = capsys.readouterr().out
    for layout in SOURCE_LAYOUTS:
        assert f"  {layout.name}: {layout.files}; poses: {layout.poses}" in out
    assert "--poses FILE" in out and ".log" in out
