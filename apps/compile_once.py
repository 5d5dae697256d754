"""Compile each numba kernel once across the processes of a first run.

On a first run ``scripts/main.sh`` starts :mod:`apps.warmup` beside the main job, so that kernels
compile on the other core; both processes compile lazily, and when both reach the same kernel each
compiled it (a trace of a cold run: the main job compiled the colour pairs' kernel for 8 s while the
warm-up compiled it again 11 s later). With :func:`install`, every compile of a cached numba
function first takes an exclusive lock on a file named after the function in ``lock_dir``: the
second process to reach a kernel waits for the first to finish it, then numba loads it from its
on-disk cache instead of compiling it. The locks are ``flock`` locks, released by the kernel when
a process exits, so a warm-up that dies never blocks the main job. Call graphs of kernels have no
cycles, so two processes never wait for each other.

    RGBD_ENVMAP_COMPILE_LOCKS=DIR   (set by scripts/main.sh on a first run; read by apps.cli)
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

__all__ = ["install", "ENV"]

ENV = "RGBD_ENVMAP_COMPILE_LOCKS"
_installed: Path | None = None


def install(lock_dir: str | os.PathLike) -> None:
    """Make this process's numba compiles of cached functions wait for other processes compiling
    the same function (see the module docstring). Idempotent."""
    global _installed
    from numba.core.caching import NullCache
    from numba.core.dispatcher import Dispatcher

    lock_dir = Path(lock_dir)
    lock_dir.mkdir(parents=True, exist_ok=True)
    if _installed is not None:
        _installed = lock_dir
        return
    _installed = lock_dir
    compile_ = Dispatcher.compile

    def compile_once(self, sig):
        if isinstance(self._cache, NullCache) or _installed is None:
            return compile_(self, sig)
        name = f"{self.py_func.__module__}.{self.py_func.__qualname__}.lock"
        with open(_installed / name, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released on close, or when the process exits
            return compile_(self, sig)  # loads from the cache what the other process just saved

    Dispatcher.compile = compile_once


def install_from_env() -> None:
    """:func:`install` with ``$RGBD_ENVMAP_COMPILE_LOCKS``, if set."""
    lock_dir = os.environ.get(ENV)
    if lock_dir:
        install(lock_dir)
