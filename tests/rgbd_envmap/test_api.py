"""``rgbd_envmap.replay``: the one-call API reproduces the CLI's replay bit for bit, on a session log
and on a TUM RGB-D sequence; unknown folders fail with the layouts known; ``max_packets`` stops early."""

import numpy as np
import pytest

import rgbd_envmap
from apps.cli import main
from rgbd_envmap.config import load_yaml
from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.logs import SessionLog
from rgbd_envmap.pipeline import DEPTH_TOTAL, PipelineConfig
from rgbd_envmap.sources.frames import SessionLogSource, as_source, detect_source_layout
from tests.apps.dataset_writers import write_icl_nuim, write_tum_published

SMALL = ["--em-size", "500x250", "--no-render", "--no-video", "--quiet"]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "--duration", "1.0", "--out", str(out), "--seed", "1", "--colour-size", "320x180", *SMALL]) == 0
    replayed = out / "replayed"
    assert main(["replay", str(out / "session"), "--out", str(replayed), *SMALL]) == 0
    return out / "session", replayed


def _assert_same_map(result, npz_path):
    with np.load(npz_path) as z:
        np.testing.assert_array_equal(result.envmap.radiance, z["radiance"])
        np.testing.assert_array_equal(result.envmap.depth_m, z["depth_m"])
        np.testing.assert_array_equal(result.envmap.valid, z["valid"])
        np.testing.assert_array_equal(result.envmap.origin, z["origin"])


def test_replay_of_a_session_log_is_the_cli_replay_bit_for_bit(session):
    root, cli = session
    config = load_yaml(PipelineConfig, cli / "config.yaml")
    result = rgbd_envmap.replay(root, config)
    _assert_same_map(result, cli / "envmap.npz")
    assert result.steps == 5 and result.packets == 35 and result.skipped == {}
    assert result.coefficients.shape == (config.shading.bands ** 2, 3) and np.isfinite(result.coefficients).all()
    assert result.timing[DEPTH_TOTAL]["count"] == 5 and result.timing[DEPTH_TOTAL]["p95_ms"] > 0
    assert 0 < result.accuracy["em_coverage"] <= 1 and np.isfinite(result.accuracy["em_ws_psnr_db"])
    np.testing.assert_array_equal(result.origin, [0.0, 0.0, 0.8])  # the true map's origin


def test_an_open_log_and_another_origin(session):
    root, cli = session
    config = load_yaml(PipelineConfig, cli / "config.yaml")
    result = rgbd_envmap.replay(SessionLog.open(root), config, origin=(0.1, 0.0, 0.8))
    np.testing.assert_allclose(result.envmap.origin, [0.1, 0.0, 0.8])
    assert result.accuracy == {}  # the truth is at another origin: not compared
    assert isinstance(as_source(SessionLog.open(root)), SessionLogSource)


def test_the_default_config_renders_nothing_and_a_truth_of_another_size_is_not_compared(session):
    root, _ = session
    result = rgbd_envmap.replay(root, max_packets=8)  # default map 2000×1000, the truth 500×250
    assert result.envmap.valid.shape == (1000, 2000) and result.accuracy == {}
    assert result.packets == 8 and "Rasterise" not in result.timing


def test_max_packets_stops_early(session):
    root, cli = session
    config = load_yaml(PipelineConfig, cli / "config.yaml")
    few = rgbd_envmap.replay(root, config, max_packets=7)
    assert few.packets == 7 and 0 < few.steps < 5
    assert rgbd_envmap.replay(root, config, max_packets=0).steps == 0
    with pytest.raises(InvalidInputError, match="max_packets"):
        rgbd_envmap.replay(root, config, max_packets=-1)


def test_unreadable_packets_are_skipped_and_counted(session, tmp_path):
    import shutil

    root, cli = session
    copy = tmp_path / "session"
    shutil.copytree(root, copy)
    ply = sorted((copy / "depth").glob("*.ply"))[1]
    ply.write_bytes(ply.read_bytes()[:40])
    result = rgbd_envmap.replay(copy, load_yaml(PipelineConfig, cli / "config.yaml"))
    assert result.skipped == {"depth": 1} and result.steps == 4


def test_a_tum_sequence_replays_as_the_cli_does(tmp_path):
    K = np.array([[517.3, 0.0, 318.6], [0.0, 516.5, 255.3], [0.0, 0.0, 1.0]])
    root = tmp_path / "rgbd_dataset_freiburg1_test"
    write_tum_published(root, K, None, n_frames=8)
    assert detect_source_layout(root).name == "TUM RGB-D"
    out = tmp_path / "run"
    assert main(["replay", str(root), "--out", str(out), "--em-size", "200x100", "--no-render", "--no-video", "--quiet"]) == 0
    result = rgbd_envmap.replay(root, load_yaml(PipelineConfig, out / "config.yaml"))
    _assert_same_map(result, out / "envmap.npz")
    assert result.packets == 8 and result.steps == 2 and "Warp + merge depth (Kinect)" in result.timing
    assert result.accuracy == {}  # no true map beside a published sequence


def test_an_icl_nuim_sequence_replays_as_the_cli_does(tmp_path):
    root = tmp_path / "living_room_traj0_frei_png"
    write_icl_nuim(root, n_frames=6)
    assert detect_source_layout(root).name == "ICL-NUIM"
    out = tmp_path / "run"
    assert main(["replay", str(root), "--out", str(out), "--em-size", "200x100", "--no-render", "--no-video", "--quiet"]) == 0
    result = rgbd_envmap.replay(root, load_yaml(PipelineConfig, out / "config.yaml"))
    _assert_same_map(result, out / "envmap.npz")
    assert result.packets == 6


def test_a_phone_capture_replays_as_the_cli_does(tmp_path):
    from tests.rgbd_envmap import phone_helpers as hand

    root = tmp_path / "capture"
    hand.write_capture(root)
    assert detect_source_layout(root).name == "phone (Stray Scanner)"
    out = tmp_path / "run"
    assert main(["replay", str(root), "--out", str(out), "--em-size", "200x100", "--no-render", "--no-video", "--quiet"]) == 0
    result = rgbd_envmap.replay(root, load_yaml(PipelineConfig, out / "config.yaml"))
    _assert_same_map(result, out / "envmap.npz")
    assert result.packets > 0 and result.steps > 0 and result.envmap.valid.any()


def test_an_unknown_folder_names_the_layouts_and_the_files(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(LogFormatError) as err:
        rgbd_envmap.replay(tmp_path)
    message = str(err.value)
    for name in ("TUM RGB-D", "ICL-NUIM", "Stray Scanner", "session log", "notes.txt"):
        assert name in message
    with pytest.raises(LogFormatError, match="not a folder"):
        rgbd_envmap.replay(tmp_path / "missing")
    with pytest.raises(InvalidInputError, match="source"):
        rgbd_envmap.replay(42)


def test_replay_is_loaded_lazily():
    import subprocess
    import sys

    code = "import sys, rgbd_envmap; assert 'rgbd_envmap.api' not in sys.modules; rgbd_envmap.replay; print('ok')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "ok", out.stderr[-2000:]
    with pytest.raises(AttributeError):
        rgbd_envmap.no_such_name
