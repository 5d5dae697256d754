"""The result of rasterisation: :class:`Layer`, and the renderer's error type.

A layer holds, for one colour frame, the object's shaded colour and coverage and the shadow plane's
alpha, in the frame's pixel grid; :func:`rgbd_envmap.render.composite.composite` draws it over the
frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_array, check_number
from rgbd_envmap.errors import InvalidInputError, RangeError, RgbdEnvmapError
from rgbd_envmap.types import MAX_IMAGE_PIXELS

__all__ = ["Layer", "RendererUnavailableError"]


class RendererUnavailableError(RgbdEnvmapError, RuntimeError):
    """The requested backend cannot run here (e.g. no EGL / OpenGL context), or the renderer is closed."""


@dataclass(frozen=True, eq=False)
class Layer:
    """What the rasteriser produced for one frame (read-only arrays).

    Attributes:
        colour: (H, W, 3) float32 linear RGB of the object in the **reference** colour space (what
            the PRT shading produced), Gouraud-interpolated; 0 outside ``mask``. Negative vertex colours
            are clamped to 0 before interpolation; values above 1 are kept.
        mask: (H, W) bool, True where the object is the nearest surface.
        plane_alpha: (H, W) float32 in [0, 1], the shadow plane's interpolated alpha where the plane is
            the nearest surface; 0 where the plane is not visible or the object hides it.
        bbox: (row0, row1, col0, col1), half-open, a rectangle outside which every array is zero (and
            ``mask`` False), or None when nothing is visible. :func:`composite` works inside it only.
    """

    colour: np.ndarray
    mask: np.ndarray
    plane_alpha: np.ndarray
    bbox: tuple[int, int, int, int] | None

    def __post_init__(self) -> None:
        colour = check_array(self.colour, "Layer.colour", shape=("H", "W", 3), dtype=np.float32)
        h, w = colour.shape[:2]
        mask = check_array(self.mask, "Layer.mask", shape=(h, w), dtype=np.bool_)
        alpha = check_array(self.plane_alpha, "Layer.plane_alpha", shape=(h, w), dtype=np.float32)
        if self.bbox is not None:
            r0, r1, c0, c1 = (int(x) for x in self.bbox)
            if not (0 <= r0 < r1 <= h and 0 <= c0 < c1 <= w):
                raise InvalidInputError(
                    f"Layer.bbox: expected 0 <= row0 < row1 <= {h} and 0 <= col0 < col1 <= {w}, got {self.bbox}")
            object.__setattr__(self, "bbox", (r0, r1, c0, c1))
        for name, arr in (("colour", colour), ("mask", mask), ("plane_alpha", alpha)):
            if arr.flags.writeable:
                arr = arr.view()
                arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def empty(cls, height: int, width: int) -> Layer:
        """A layer with nothing visible (what an object behind the camera or out of view gives); at
        most :data:`rgbd_envmap.types.MAX_IMAGE_PIXELS` pixels (20 bytes each)."""
        height = check_number(height, "height", low=1, integer=True)
        width = check_number(width, "width", low=1, integer=True)
        if height * width > MAX_IMAGE_PIXELS:
            raise RangeError(f"height×width: expected at most {MAX_IMAGE_PIXELS:,} pixels, got {height}×{width}; "
                             f"the layer would take about {height * width * 20 / 2**30:.3g} GiB")
        return cls(np.zeros((height, width, 3), np.float32), np.zeros((height, width), bool),
                   np.zeros((height, width), np.float32), None)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width)."""
        return self.mask.shape

    @property
    def is_empty(self) -> bool:
        """True when neither the object nor the plane covers a pixel."""
        if self.bbox is None:
            return True
        r0, r1, c0, c1 = self.bbox
        return not (self.mask[r0:r1, c0:c1].any() or self.plane_alpha[r0:r1, c0:c1].any())
