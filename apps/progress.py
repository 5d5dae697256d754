"""Progress bars of the apps: shown only on a terminal.

``disable=None`` makes tqdm draw a bar only when its stream (stderr) is a terminal, so the log of a
redirected or piped run stays readable; ``TQDM_DISABLE=1`` in the environment turns every bar off
(tqdm reads that variable only for an argument not given, and the apps give ``disable``, so it is
read here); ``--quiet`` turns them off explicitly.
"""

from __future__ import annotations

import os

__all__ = ["bar_disable"]


def bar_disable(progress: bool) -> bool | None:
    """tqdm's ``disable`` for an app asked to show progress (``progress``) or not: None (tqdm's own
    terminal test) when asked and ``TQDM_DISABLE`` is not set to a true value, True otherwise."""
    if not progress or os.environ.get("TQDM_DISABLE", "").strip().lower() in ("1", "true", "yes", "on"):
        return True
    return None
