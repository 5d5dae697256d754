"""Phone captures (Stray Scanner layout) replay end to end through the mobile path: a simulated one
gives the map the simulator's own packets give, a hand-written one puts ARKit's ceiling at the map's
zenith, and broken files are skipped and counted."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from apps.phone import is_phone_capture, run_replay_phone, run_simulate_phone
from apps.replay import ReplayOptions
from apps.simulate import SimulateOptions
from rgbd_envmap import metrics
from rgbd_envmap.colour import srgb_to_linear
from rgbd_envmap.config import apply_overrides
from rgbd_envmap.errors import LogFormatError
from rgbd_envmap.geometry import directions_to_equirect, equirect_pixel_index
from rgbd_envmap.pipeline import Pipeline, PipelineConfig
from sim.phone import phone_device
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory
from tests.rgbd_envmap import phone_helpers as hand

CONFIG = apply_overrides(PipelineConfig(), ["capture.width=500", "capture.height=250", "render.enabled=false"])


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("phone") / "run"
    summary = run_simulate_phone(SimulateOptions(duration_s=1.0, out=out, colour_width=320, colour_height=240, seed=0,
                                                 config=CONFIG, video=False, progress=False, device="phone"))
    return out, summary


def _map(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_a_simulated_phone_capture_replays_to_the_map_of_its_own_packets(simulated):
    out, summary = simulated
    session = Path(summary["session"])
    assert is_phone_capture(session) and summary["depth_packets"] == 5 and summary["colour_packets"] == 30
    run = json.loads((out / "run.json").read_text())
    assert run["depth_frames_processed"] == 5 and run["skipped"] == {} and "phone" in run["source"]
    acc = json.loads((out / "accuracy.json").read_text())
    assert acc["em_coverage"] > 0.08 and acc["em_ws_psnr_db"] > 15.0  # measured 0.104, 17.3 dB after 1 s
    assert "ingest_depth_mae_m" in acc and "ccm_matrix_rel_error_median" in acc  # the per-frame truth was found
    # the simulator's packets fed to the pipeline directly (no files, no video): the same map, nearly
    sim = Simulator(load_scene("office"), load_trajectory("orbit"), phone_device(320, 240), seed=0)
    truth = _map(session / "groundtruth" / "envmap.npz")
    with Pipeline(CONFIG, sim.calibration, truth["origin"]) as pipe:
        for sp in sim.run(1.0):
            pipe.feed(sp.packet)
        pipe.finish()
        direct = pipe.capture.em
    replayed = _map(out / "envmap.npz")
    gv = truth["valid"]
    psnr = {}
    for name, valid, radiance in (("direct", direct.valid, direct.radiance), ("replayed", replayed["valid"], replayed["radiance"])):
        both = valid & gv
        psnr[name] = metrics.ws_psnr(np.clip(radiance, 0, 1), np.clip(truth["radiance"], 0, 1), both)
    assert abs(psnr["replayed"] - psnr["direct"]) < 0.5  # dB
    assert abs(metrics.coverage_of(replayed["valid"], gv) - metrics.coverage_of(direct.valid, gv)) < 0.01


@pytest.fixture(scope="module")
def hand_capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("hand") / "capture"
    hand.write_capture(root)
    return root


def _pixel(direction, h, w):
    d = np.asarray([direction], float)
    row, col, _ = equirect_pixel_index(d, h, w)
    return int(row[0]), int(col[0])


def test_a_hand_written_capture_puts_arkit_up_at_the_zenith(hand_capture, tmp_path):
    origin = tuple(float(v) for v in (hand.POSITION_ARKIT[0], -hand.POSITION_ARKIT[2], hand.POSITION_ARKIT[1]))
    # six views that hardly overlap, taken far apart in a short time: no colour correction, no pose-jump check
    config = apply_overrides(CONFIG, ["capture.colour_correction=false", "pose_check.enabled=false"])
    summary = run_replay_phone(ReplayOptions(hand_capture, tmp_path / "run", origin=origin, config=config, video=False,
                                             progress=False), depth_rate_hz=None)
    assert summary["depth_frames_processed"] == 6 and summary["em_origin"] == list(origin)
    em = _map(tmp_path / "run" / "envmap.npz")
    h, w = em["valid"].shape
    linear = {k: srgb_to_linear(np.asarray(v) / 255.0) for k, v in hand.WALLS.items()}
    cases = [((0, 0, 1), ("y", 1), hand.HALF - 0.2),  # our zenith: ARKit's ceiling, 1.8 m above the camera
             ((0, 1, 0), ("z", -1), hand.HALF + 0.3),  # our +y: ARKit −z, the first view's wall
             ((0, 0, -1), ("y", -1), hand.HALF + 0.2),  # nadir: the floor
             ((1, 0, 0), ("x", 1), hand.HALF - 0.1)]
    for direction, wall, distance in cases:
        r, c = _pixel(direction, h, w)
        r = min(max(r, 3), h - 4)  # off the pole row
        assert em["valid"][r, c], direction
        np.testing.assert_allclose(em["radiance"][r, c], linear[wall], atol=0.03, err_msg=str(direction))
        assert em["depth_m"][r, c] == pytest.approx(distance, abs=0.02)
    assert directions_to_equirect(np.array([[0.0, 1.0, 0.0]]), h, w)[0, 0] == pytest.approx(3 * w / 4 - 0.5)


def test_an_unreadable_depth_image_is_skipped_and_counted_or_ends_a_strict_replay(hand_capture, tmp_path):
    copy = tmp_path / "c"
    shutil.copytree(hand_capture, copy)
    victim = copy / "depth" / "000001.png"
    victim.write_bytes(victim.read_bytes()[:64])
    config = apply_overrides(CONFIG, ["capture.colour_correction=false", "pose_check.enabled=false"])
    summary = run_replay_phone(ReplayOptions(copy, tmp_path / "run", config=config, video=False, progress=False), depth_rate_hz=None)
    assert summary["skipped"] == {"depth": 1} and "000001.png" in summary["skipped_files"][0]
    assert summary["depth_frames_processed"] == 5 and summary["colour_packets"] == 6
    # no ground truth beside a hand-written capture: the origin is 1 m in front of the first camera
    np.testing.assert_allclose(summary["em_origin"], [0.1, 0.7, 0.2], atol=1e-12)
    with pytest.raises(LogFormatError, match="000001.png"):
        run_replay_phone(ReplayOptions(copy, tmp_path / "strict", config=config, video=False, progress=False, strict=True),
                         depth_rate_hz=None)
