"""The project's error hierarchy.

Every error raised on purpose by ``rgbd_envmap`` (and by ``sim`` and ``apps``) derives from
:class:`RgbdEnvmapError`. The concrete classes also derive from the matching builtin, so a caller may
catch either ``ShapeError`` or plain ``ValueError``.
"""

from __future__ import annotations

__all__ = [
    "RgbdEnvmapError",
    "InvalidInputError",
    "ShapeError",
    "DTypeError",
    "NonFiniteError",
    "RangeError",
    "UnknownMethodError",
    "FrameError",
    "LogFormatError",
]


class RgbdEnvmapError(Exception):
    """Base class of every error the project raises on purpose."""


class InvalidInputError(RgbdEnvmapError, ValueError):
    """An argument has a value the function cannot work with."""


class ShapeError(InvalidInputError):
    """An array argument has the wrong number of dimensions or the wrong size along one."""


class DTypeError(RgbdEnvmapError, TypeError):
    """An array argument has a dtype the function does not accept."""


class NonFiniteError(InvalidInputError):
    """An argument holds NaN or infinity where only finite values are allowed."""


class RangeError(InvalidInputError):
    """An argument holds values outside the allowed interval."""


class UnknownMethodError(InvalidInputError):
    """A method name is not one of the registered ones; the message lists the valid names."""


class FrameError(InvalidInputError):
    """A transform's frame names are not those the argument needs (``T_depth_from_world`` passed as a
    packet's ``T_world_from_depth``); the message names the argument, the frames expected and given.
    Unnamed frames (``""``) are taken as they come."""


class LogFormatError(RgbdEnvmapError, ValueError):
    """A session log on disk is missing a file or holds malformed data; the message names the file
    (and the line, for text files)."""
