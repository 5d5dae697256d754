"""simulate (pipeline live) → run folder; replay reproduces it; report regenerates it; bad logs."""

import csv
import json
import os
import shutil

import numpy as np
import pytest

from apps.cli import main
from apps.report import write_reports
from rgbd_envmap.pipeline import COLOUR_TOTAL, DEPTH_TOTAL

SMALL = ["--colour-size", "320x180", "--em-size", "500x250", "--no-render", "--quiet", "--preview-envmap-height", "32"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "--duration", "1.0", "--out", str(out), "--seed", "1", *SMALL]) == 0
    return out


def test_simulate_writes_the_run_folder(run):
    for name in ("envmap.npz", "envmap.png", "envmap_depth.png", "composites.mp4", "timing.csv", "timing.md", "timing.png",
                 "accuracy.json", "depth_frames.csv", "config.yaml", "run.json", "stage_times.csv", "session/calibration.json",
                 "session/groundtruth/envmap.npz"):
        assert (run / name).stat().st_size > 0, name
    assert list((run / "composites").glob("*.png"))
    with np.load(run / "envmap.npz") as z:
        assert set(z.files) == {"radiance", "depth_m", "valid", "origin"}
        assert z["radiance"].shape == (250, 500, 3) and z["radiance"].dtype == np.float32
        assert z["valid"].dtype == bool and z["valid"].any()
        np.testing.assert_array_equal(z["origin"], [0.0, 0.0, 0.8])
    acc = json.loads((run / "accuracy.json").read_text())
    for key in ("em_coverage", "em_ws_psnr_db", "ingest_depth_mae_m", "hole_filling_depth_mae_m", "ccm_matrix_rel_error_median",
                "sh_coeff_rel_error", "irradiance_rel_error_mean"):
        assert np.isfinite(acc[key]), key
    assert 0 < acc["em_coverage"] <= 1
    assert acc["depth_frames"] == 5


def test_timing_csv_has_every_stage_and_the_totals(run):
    rows = {r["stage"]: r for r in csv.DictReader(open(run / "timing.csv"))}
    for stage in ("Point cloud to RGB-D", "Mark reliable RGB-D", "Hole filling RGB-D", "Collect paired samples",
                  "Compute colour correction matrix", "Project sample to EM*", "Calculate SH coefficients*", DEPTH_TOTAL, COLOUR_TOTAL):
        assert stage in rows, stage
        assert float(rows[stage]["median_ms"]) > 0 and float(rows[stage]["p95_ms"]) >= float(rows[stage]["median_ms"])
    assert int(rows[DEPTH_TOTAL]["count"]) == 5 and int(rows[COLOUR_TOTAL]["count"]) == 30
    md = (run / "timing.md").read_text()
    assert "13.97" in md and "em_ws_psnr_db" in md  # the paper's figure beside ours, and the errors


def test_replay_of_the_recorded_session_reproduces_the_map_bit_for_bit(run, tmp_path):
    out = tmp_path / "replay"
    assert main(["replay", str(run / "session"), "--out", str(out), *SMALL[2:6]]) == 0
    with np.load(run / "envmap.npz") as a, np.load(out / "envmap.npz") as b:
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert json.loads((out / "accuracy.json").read_text()) == json.loads((run / "accuracy.json").read_text())


def test_depth_frames_the_capture_rejects_are_counted_by_reason_and_printed(run, tmp_path, capsys):
    assert json.loads((run / "run.json").read_text())["depth_frames_rejected"] == {}
    out = tmp_path / "rejecting"
    # no frame after the reference can have a million pairs: every one is "too few pairs"
    assert main(["replay", str(run / "session"), "--out", str(out), "--set", "capture.min_pairs=1000000", *SMALL[2:6]]) == 0
    rejected = json.loads((out / "run.json").read_text())["depth_frames_rejected"]
    rows = list(csv.DictReader(open(out / "depth_frames.csv")))
    assert rejected == {"too few pairs": 4} and sum(r["reason"].startswith("too few pairs") for r in rows) == 4
    assert "depth frames not projected into the map: 4 (too few pairs 4;" in capsys.readouterr().out


def test_replay_with_other_settings_and_origin(run, tmp_path):
    out = tmp_path / "other"
    assert main(["replay", str(run / "session"), "--out", str(out), "--origin", "0.1", "0", "0.8", "--set", "capture.colour_correction=false",
                 "--set", "shading.bands=3", *SMALL[2:6]]) == 0
    with np.load(out / "envmap.npz") as z:
        np.testing.assert_allclose(z["origin"], [0.1, 0.0, 0.8])
    acc = json.loads((out / "accuracy.json").read_text())
    assert "em_coverage" not in acc  # the true map is at another origin: not compared, not guessed
    assert "capture:\n" in (out / "config.yaml").read_text() and "bands: 3" in (out / "config.yaml").read_text()


def test_report_regenerates_the_reports(run, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(run, copy, ignore=shutil.ignore_patterns("session", "composites*"))
    for name in ("timing.csv", "timing.md", "timing.png"):
        (copy / name).unlink()
    assert main(["report", str(copy)]) == 0
    assert (copy / "timing.csv").read_text() == (run / "timing.csv").read_text()


def test_report_of_a_folder_without_timings_fails_clearly(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 1  # a data error
    assert "stage_times.csv" in capsys.readouterr().err


@pytest.fixture()
def log_copy(run, tmp_path):
    dst = tmp_path / "log"
    shutil.copytree(run / "session", dst)
    return dst


def test_truncated_colour_png_is_skipped_and_counted(log_copy, tmp_path):
    victim = sorted((log_copy / "colour").glob("*.png"))[7]
    victim.write_bytes(victim.read_bytes()[:100])
    out = tmp_path / "r"
    assert main(["replay", str(log_copy), "--out", str(out), *SMALL[2:6]]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["skipped"] == {"colour": 1} and victim.name in info["skipped_files"][0]
    assert info["colour_packets"] == 29


def test_truncated_png_with_strict_stops_naming_the_file(log_copy, tmp_path, capsys):
    victim = sorted((log_copy / "colour").glob("*.png"))[3]
    victim.write_bytes(victim.read_bytes()[:100])
    assert main(["replay", str(log_copy), "--out", str(tmp_path / "r"), "--strict", *SMALL[2:6]]) == 1
    assert victim.name in capsys.readouterr().err


@pytest.mark.parametrize("damage, message", [
    ("unsorted", "line 5"),
    ("nan_pose", "NaN"),
    ("missing_file", "depth_poses.txt: missing file"),
])
def test_bad_index_files_fail_naming_file_and_line(log_copy, tmp_path, capsys, damage, message):
    if damage == "unsorted":
        lines = (log_copy / "depth.txt").read_text().splitlines(keepends=True)
        lines[3], lines[4] = lines[4], lines[3]  # two comment lines first
        (log_copy / "depth.txt").write_text("".join(lines))
    elif damage == "nan_pose":
        lines = (log_copy / "colour_poses.txt").read_text().splitlines(keepends=True)
        fields = lines[2].split()
        fields[1] = "nan"
        lines[2] = " ".join(fields) + "\n"
        (log_copy / "colour_poses.txt").write_text("".join(lines))
    else:
        (log_copy / "depth_poses.txt").unlink()
    assert main(["replay", str(log_copy), "--out", str(tmp_path / "r"), *SMALL[2:6]]) == 1
    err = capsys.readouterr().err
    assert message.lower() in err.lower()


def test_report_renders_every_stage_error_beside_its_stage(run):
    table = write_reports(run)
    assert table[DEPTH_TOTAL]["count"] == 5


def test_rerun_recording_holds_frames_map_and_metrics(run, tmp_path):
    rrd = tmp_path / "run.rrd"
    assert main(["replay", str(run / "session"), "--out", str(tmp_path / "r"), "--rerun", str(rrd), "--no-video", *SMALL[2:6]]) == 0
    data = rrd.read_bytes()
    assert len(data) > 10_000
    for entity in (b"world/colour_camera", b"envmap/colour", b"envmap/depth", b"metrics/pairs", b"world/em_origin"):
        assert entity in data, entity


def test_smaller_map_is_scored_against_the_box_averaged_truth(run, tmp_path):
    out = tmp_path / "small"
    assert main(["replay", str(run / "session"), "--out", str(out), "--em-size", "250x125", "--no-render", "--no-video", "--quiet"]) == 0
    acc = json.loads((out / "accuracy.json").read_text())
    assert acc["em_truth_downsampled"] == 1.0 and 0 < acc["em_coverage"] <= 1 and np.isfinite(acc["em_ws_psnr_db"])


def test_sweep_writes_time_and_error_side_by_side(run, tmp_path):
    out = tmp_path / "sweep"
    assert main(["sweep", str(run / "session"), "--out", str(out), "--axes", "translation", "--jobs", "2", "--quiet"]) == 0
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    names = [r["setting"] for r in rows]
    assert names == ["default", "translate 10 cm: depth", "translate 10 cm: gardner"]
    for r in rows[1:]:
        assert float(r["axis_stage_median_ms"]) > 0 and 0 < float(r["translation_sphere_correlation"]) <= 1
    assert (out / "pareto.png").stat().st_size > 0 and "| translation |" in (out / "sweep.md").read_text()


def test_sweep_rejects_unknown_axes(run, tmp_path, capsys):
    assert main(["sweep", str(run / "session"), "--out", str(tmp_path / "s"), "--axes", "colour_of_the_sky", "--quiet"]) == 2
    assert "colour_of_the_sky" in capsys.readouterr().err


def test_video_writer_encodes_every_frame_niced_and_pads_odd_sizes(tmp_path):
    """The encoder gets every frame (read back: count, size, content), odd sizes padded to even."""
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    from apps.run import VideoWriter

    path = tmp_path / "v.mp4"
    video = VideoWriter(path, 30.0)
    for i in range(12):
        video.write(np.full((17, 31, 3), 20 * i, np.uint8))
        if i == 0 and video._proc is not None:  # the encoder runs niced (the pipeline keeps its core)
            assert os.getpriority(os.PRIO_PROCESS, video._proc.pid) == min(19, os.getpriority(os.PRIO_PROCESS, 0) + 19)
    video.close()
    frames = imageio_ffmpeg.read_frames(str(path))
    meta = next(frames)
    assert meta["size"] == (32, 18)
    means = [np.frombuffer(f, np.uint8).reshape(18, 32, 3)[:17, :31].mean() for f in frames]
    assert len(means) == 12
    np.testing.assert_allclose(means, 20 * np.arange(12), atol=3)


def test_nan_points_are_dropped_and_counted_an_all_nan_packet_skipped_and_strict_stops(log_copy, tmp_path, capsys):
    from rgbd_envmap.logs import SessionLog, _ply_bytes

    log = SessionLog.open(log_copy)
    plies = sorted((log_copy / "depth").glob("*.ply"))
    some, every = plies[2], plies[4]
    p = log.read_depth(2)
    pts = p.points_m.copy()
    pts[:7, 0] = np.nan
    some.write_bytes(_ply_bytes(pts, p.confidence))
    every.write_bytes(_ply_bytes(np.full((3, 3), np.nan, np.float32), np.ones(3, np.float32)))
    out = tmp_path / "r"
    assert main(["replay", str(log_copy), "--out", str(out), *SMALL[2:6]]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["dropped_points"] == {f"depth/{some.name}": 7}
    assert info["skipped"].get("depth") == 1 and every.name in " ".join(info["skipped_files"])
    assert main(["replay", str(log_copy), "--out", str(tmp_path / "s"), "--strict", *SMALL[2:6]]) == 1
    assert some.name in capsys.readouterr().err  # the first file with a NaN point stops a strict run


def test_an_empty_index_is_a_warning_on_the_terminal_and_in_run_json(log_copy, tmp_path, capsys):
    text = (log_copy / "depth.txt").read_text().splitlines(keepends=True)
    (log_copy / "depth.txt").write_text("".join(line for line in text if line.startswith("#")))
    out = tmp_path / "r"
    main(["replay", str(log_copy), "--out", str(out), *SMALL[2:6]])
    assert "warning" in capsys.readouterr().err and "empty index" in (out / "run.json").read_text()
