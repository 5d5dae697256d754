"""Run folders that never lose data: each command writes into a new folder and moves it into place
only when it is complete.

:func:`staged_run` is how ``simulate`` and ``replay`` write their ``--out``:

- an existing non-empty ``--out`` is refused (:class:`OutputExistsError`, one line) unless
  ``overwrite``; with it, the old folder is replaced only at the moment the new one is complete;
- the command writes into ``.<name>.partial-<pid>`` beside ``--out`` (same file system, so the final
  move is a rename);
- an interrupt (Ctrl-C, SIGTERM) or an error leaves the earlier folder untouched and the partial one
  in place, marked: its ``run.json`` gets ``"status": "interrupted"`` (or ``"failed"``), the reason and
  the files it holds; the session log inside stays replayable (its indices are written as it goes);
- an unwritable location fails at once with the path and the reason.

SIGTERM is turned into :class:`Terminated` (a ``KeyboardInterrupt``) while a staged run is open, so
the same clean-up runs; the command line exits 130 on Ctrl-C and 143 on SIGTERM.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from rgbd_envmap.errors import RgbdEnvmapError

__all__ = ["staged_run", "OutputExistsError", "Terminated", "partial_path"]


class OutputExistsError(RgbdEnvmapError, FileExistsError):
    """``--out`` already holds something and ``--overwrite`` was not given."""


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived during a staged run."""


def partial_path(out: Path) -> Path:
    """Where a run into ``out`` is written until it is complete."""
    return out.parent / f".{out.name}.partial-{os.getpid()}"


def _mark(partial: Path, status: str, reason: str) -> None:
    """Record in ``partial/run.json`` that the run did not complete, and what the folder holds."""
    run_json = partial / "run.json"
    try:
        info = json.loads(run_json.read_text()) if run_json.is_file() else {}
    except (OSError, ValueError):
        info = {}
    held = sorted(str(p.relative_to(partial)) for p in partial.rglob("*") if p.is_file() and p != run_json)
    info.update(status=status, reason=reason, files=len(held), holds=sorted({h.split("/")[0] for h in held}))
    try:
        run_json.write_text(json.dumps(info, indent=2) + "\n")
    except OSError:
        pass  # nothing more can be done for a folder that cannot be written


@contextmanager
def staged_run(out: str | os.PathLike, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a fresh folder to write the run into; move it to ``out`` when the block completes (see
    the module docstring). Raises :class:`OutputExistsError` before anything is written when ``out``
    is a non-empty folder (or a file) and ``overwrite`` is False, and ``OSError`` naming the path when
    the location cannot be written."""
    out = Path(out)
    if out.exists() and not overwrite and (not out.is_dir() or any(out.iterdir())):
        raise OutputExistsError(f"{out}: exists and is not empty (pass --overwrite to replace it when the new run is complete)")
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = partial_path(out)
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir()

    def on_sigterm(signum, frame):
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, on_sigterm) if _main_thread() else None
    try:
        yield partial
    except KeyboardInterrupt as exc:
        _mark(partial, "interrupted", "SIGTERM" if isinstance(exc, Terminated) else "SIGINT")
        raise
    except BaseException as exc:
        _mark(partial, "failed", f"{type(exc).__name__}: {exc}")
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    # Complete: paths recorded in the run's JSON files name the final folder, and the new folder takes
    # the old one's place in two renames.
    for path in partial.glob("*.json"):
        text = path.read_text()
        if str(partial) in text:
            path.write_text(text.replace(str(partial), str(out)))
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        out.rename(old)
        partial.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        partial.rename(out)


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()
