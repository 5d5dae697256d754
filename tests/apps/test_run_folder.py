"""Run folders never lose data: refusals without --overwrite, replacement only when complete, and
interrupted or failed runs leaving the earlier folder intact and the partial one marked."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from apps.cli import main
from apps.run_folder import OutputExistsError, Terminated, partial_path, staged_run

ROOT = Path(__file__).resolve().parents[2]
SMALL = ["--colour-size", "96x64", "--em-size", "200x100", "--no-render", "--no-video", "--quiet",
         "--preview-envmap-height", "16"]


def _earlier_run(path: Path) -> dict[str, bytes]:
    path.mkdir(parents=True)
    files = {"envmap.npz": b"old map", "accuracy.json": b'{"old": 1}\n', "notes.txt": b"mine"}
    for name, data in files.items():
        (path / name).write_bytes(data)
    return files


def _intact(path: Path, files: dict[str, bytes]) -> bool:
    return sorted(p.name for p in path.iterdir()) == sorted(files) and all(
        (path / n).read_bytes() == d for n, d in files.items())


def test_an_existing_folder_is_refused_without_overwrite(tmp_path, capsys):
    out = tmp_path / "run"
    files = _earlier_run(out)
    assert main(["simulate", "--duration", "0.2", "--out", str(out), *SMALL]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--overwrite" in err
    assert _intact(out, files)
    assert not list(tmp_path.glob(".run.partial-*"))  # nothing was started


def test_overwrite_replaces_the_folder_only_when_the_run_is_complete(tmp_path):
    out = tmp_path / "run"
    _earlier_run(out)
    assert main(["simulate", "--duration", "0.4", "--out", str(out), "--overwrite", *SMALL]) == 0
    assert not (out / "notes.txt").exists() and (out / "envmap.npz").stat().st_size > 100
    info = json.loads((out / "simulation.json").read_text())
    assert ".partial-" not in json.dumps(info)  # recorded paths name the final folder
    assert not list(tmp_path.glob(".run.*"))
    again = tmp_path / "again"
    assert main(["replay", str(out / "session"), "--out", str(again), *SMALL[2:7]]) == 0
    assert main(["replay", str(out / "session"), "--out", str(again), *SMALL[2:7]]) == 1  # replay refuses too
    assert main(["replay", str(out / "session"), "--out", str(again), "--overwrite", *SMALL[2:7]]) == 0


@pytest.mark.parametrize("error", [KeyboardInterrupt, Terminated, RuntimeError])
def test_an_interrupted_or_failed_run_leaves_the_earlier_folder_and_marks_the_partial_one(tmp_path, error):
    out = tmp_path / "run"
    files = _earlier_run(out)
    with pytest.raises(error):
        with staged_run(out, overwrite=True) as partial:
            (partial / "session").mkdir()
            (partial / "session" / "depth.txt").write_text("# partial\n")
            raise error()
    assert _intact(out, files)
    info = json.loads((partial_path(out) / "run.json").read_text())
    assert info["status"] == ("failed" if error is RuntimeError else "interrupted")
    assert info["reason"] == {KeyboardInterrupt: "SIGINT", Terminated: "SIGTERM"}.get(error, info["reason"])
    assert info["holds"] == ["session"] and info["files"] == 1


def test_an_unwritable_location_fails_with_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["simulate", "--duration", "0.2", "--out", str(blocker / "run"), *SMALL]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(blocker) in err and "Traceback" not in err
    with pytest.raises(OutputExistsError):
        with staged_run(blocker):
            pass


@pytest.mark.slow
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_during_simulate_exits_with_its_code_and_keeps_the_earlier_run(tmp_path, sig, code):
    out = tmp_path / "run"
    files = _earlier_run(out)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "apps.cli", "simulate", "--duration", "30", "--out", str(out),
                             "--overwrite", *SMALL], cwd=tmp_path, env=env, stderr=subprocess.PIPE, text=True)
    partial = out.parent / f".run.partial-{proc.pid}"
    deadline = time.monotonic() + 120
    index = partial / "session" / "depth.txt"

    def packets_written() -> bool:  # the index's header comes first, the packets once the device runs
        return index.exists() and any(not ln.startswith("#") for ln in index.read_text().splitlines())

    while not packets_written() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == code, err
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err and "Traceback" not in err
    assert _intact(out, files)
    info = json.loads((partial / "run.json").read_text())
    assert info["status"] == "interrupted" and "session" in info["holds"]
    from rgbd_envmap.logs import SessionLog

    log = SessionLog.open(partial / "session")  # the partial session log replays
    assert len(log) > 0
