"""Kernel of the pyrender backend: unpacking the GL read-back into the layer's arrays.

The GL colour attachment's alpha channel marks what was drawn: :data:`GL_OBJECT_ALPHA` for the
object (its rgb is the colour, scaled down for the draw), :data:`GL_PLANE_ALPHA` for the shadow
plane (its red is the plane's alpha), 0 for the clear colour. Called from
:mod:`rgbd_envmap.render.gl` only.
"""

from __future__ import annotations

import numba

__all__ = ["GL_OBJECT_ALPHA", "GL_PLANE_ALPHA", "split_rgba"]

#: Marker values in the GL colour attachment's alpha: the object writes 1, the plane 0.5, the clear 0.
GL_OBJECT_ALPHA = 1.0
GL_PLANE_ALPHA = 0.5


@numba.njit(cache=True)
def split_rgba(rgba, scale, r0, c0, colour, mask, alpha):  # pragma: no cover - compiled
    """Unpack the GL read-back ``rgba`` (h, w, 4), rows bottom-up, into the layer arrays at (r0, c0):
    alpha-channel marker 1 = object (rgb × scale is its colour), 0.5 = plane (red is its alpha)."""
    h = rgba.shape[0]
    obj_cut = 0.5 * (GL_OBJECT_ALPHA + GL_PLANE_ALPHA)
    plane_cut = 0.5 * GL_PLANE_ALPHA
    for i in range(h):
        src = rgba[h - 1 - i]
        r = r0 + i
        for j in range(rgba.shape[1]):
            marker = src[j, 3]
            if marker > obj_cut:
                c = c0 + j
                mask[r, c] = True
                colour[r, c, 0] = src[j, 0] * scale
                colour[r, c, 1] = src[j, 1] * scale
                colour[r, c, 2] = src[j, 2] * scale
            elif marker > plane_cut:
                alpha[r, c0 + j] = src[j, 0]

