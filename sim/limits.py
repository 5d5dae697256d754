"""Bounds of a simulated session: the longest one, checked before anything is allocated."""

from __future__ import annotations

from rgbd_envmap.checks import check_number

__all__ = ["MAX_DURATION_S", "check_duration"]

#: the longest session: 24 h (2.6 million colour frames at 30 Hz; a log of it would take terabytes).
MAX_DURATION_S = 86_400.0


def check_duration(duration_s: object, name: str = "duration_s") -> float:
    """``duration_s`` as a float in (0, :data:`MAX_DURATION_S`] seconds, else a typed error naming it
    (:class:`~rgbd_envmap.errors.RangeError` for inf, NaN or out of range)."""
    return check_number(duration_s, name, low=0.0, low_open=True, high=MAX_DURATION_S)

