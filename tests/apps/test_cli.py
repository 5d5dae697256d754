import json

import numpy as np
import pytest

from apps.cli import build_parser, main
from rgbd_envmap.logs import SessionLog
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory

POSE_TOL = 1e-12


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    rc = main(["simulate", "--duration", "0.6", "--out", str(out), "--colour-size", "96x64", "--seed", "3", "--quiet",
               "--preview-envmap-height", "32", "--record-only", "--em-size", "64x32"])
    assert rc == 0
    return out


def test_simulate_writes_session_preview_and_summary(recorded):
    for name in ("contact_sheet.png", "depth_confidence.png", "groundtruth_envmap.png", "groundtruth_envmap_depth.png"):
        assert (recorded / "preview" / name).stat().st_size > 0
    summary = json.loads((recorded / "simulation.json").read_text())
    assert summary["depth_packets"] == 3 and summary["colour_packets"] == 18
    assert summary["simulate_colour_packet"]["median_ms"] > 0


def test_recorded_session_reads_back_to_the_simulated_packets(recorded):
    log = SessionLog.open(recorded / "session")
    device = TangoDeviceConfig(colour=ColourCameraConfig(width=96, height=64))
    live = list(Simulator(load_scene("office"), load_trajectory("orbit"), device, seed=3).run(0.6))
    replayed = list(log)
    assert len(replayed) == len(live) == 21
    for sp, pk in zip(live, replayed):
        assert pk.kind == sp.packet.kind and pk.timestamp_ns == sp.packet.timestamp_ns
        if pk.kind == "depth":
            np.testing.assert_array_equal(pk.points_m, sp.packet.points_m)
            np.testing.assert_array_equal(pk.confidence, sp.packet.confidence)
            np.testing.assert_allclose(pk.T_world_from_depth.matrix, sp.packet.T_world_from_depth.matrix, atol=POSE_TOL)
            np.testing.assert_array_equal(log.groundtruth("depth", pk.timestamp_ns)["true_depth_m"], sp.groundtruth["true_depth_m"])
        else:
            np.testing.assert_array_equal(pk.nv21, sp.packet.nv21)
            np.testing.assert_allclose(pk.T_world_from_colour.matrix, sp.packet.T_world_from_colour.matrix, atol=POSE_TOL)
            np.testing.assert_array_equal(log.groundtruth("colour", pk.timestamp_ns)["gains"], sp.groundtruth["gains"])


def test_help_documents_every_option_with_units(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["simulate", "--help"])
    text = capsys.readouterr().out
    for flag, unit in [("--duration", "seconds"), ("--colour-size", "pixels"), ("--tracking-noise-m", "METRES"),
                       ("--tracking-noise-deg", "DEGREES"), ("--seed", "N"), ("--scene", "NAME")]:
        assert flag in text and unit in text


@pytest.mark.parametrize(
    "args, message",
    [
        (["--duration", "0"], "duration"),
        (["--duration", "1", "--scene", "nowhere"], "known scenes"),
        (["--duration", "1", "--trajectory", "nowhere"], "known trajectories"),
    ],
)
def test_bad_arguments_exit_2_with_a_message(tmp_path, capsys, args, message):
    assert main(["simulate", "--out", str(tmp_path / "x"), "--quiet", *args]) == 2
    assert message in capsys.readouterr().err


def test_bad_colour_size_is_rejected_by_the_parser(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["simulate", "--duration", "1", "--out", "x", "--colour-size", "97x64"])
    assert "even" in capsys.readouterr().err


def test_existing_session_is_not_overwritten_silently(recorded, capsys):
    assert main(["simulate", "--duration", "0.2", "--out", str(recorded), "--colour-size", "96x64", "--quiet"]) == 1
    assert "overwrite" in capsys.readouterr().err


def test_exit_codes_one_line_errors_version_and_debug(tmp_path, capsys):
    """Usage errors exit 2, data errors 1, each with one line on stderr and no traceback unless --debug."""
    from apps.cli import main as cli_main
    from rgbd_envmap import __version__
    from rgbd_envmap.errors import LogFormatError

    with pytest.raises(SystemExit) as info:
        cli_main(["--version"])
    assert info.value.code == 0 and __version__ in capsys.readouterr().out
    # a setting out of range: usage
    assert cli_main(["simulate", "--duration", "1", "--out", str(tmp_path / "a"), "--quiet",
                     "--set", "capture.update.max_splat_px=-1"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "max_splat_px" in err and "Traceback" not in err
    # a folder that is no recording: data
    (tmp_path / "empty").mkdir()
    assert cli_main(["replay", str(tmp_path / "empty"), "--out", str(tmp_path / "b"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    with pytest.raises(LogFormatError):
        cli_main(["--debug", "replay", str(tmp_path / "empty"), "--out", str(tmp_path / "c"), "--quiet"])
