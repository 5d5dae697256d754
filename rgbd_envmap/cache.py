"""The on-disk cache of derived data (extracted meshes, PRT transfer): where it lives, how it is written.

The cache directory is ``$RGBD_ENVMAP_CACHE`` if set and non-empty, else ``~/.cache/rgbd-envmap``;
callers take a ``cache_dir`` argument that overrides it. Files are written atomically (a temporary
file in the same folder, then a rename), so a reader never sees a partial file and two processes
writing the same entry leave one complete copy.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes", "default_cache_dir"]


def default_cache_dir() -> Path:
    """``$RGBD_ENVMAP_CACHE`` if set and non-empty, else ``~/.cache/rgbd-envmap`` (not created here)."""
    env = os.environ.get("RGBD_ENVMAP_CACHE", "").strip()
    return Path(env).expanduser() if env else Path.home() / ".cache" / "rgbd-envmap"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` (creating its folders) through a temporary file and a rename; the
    file is readable by everyone (mode 0644: the cache may be shared between users of a machine)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
