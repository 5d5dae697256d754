"""Rendering the virtual object into the live colour frame (paper 003 §7.2; docs/design/render.md).

- :mod:`rgbd_envmap.render.raster`: :class:`Renderer`, offscreen rasterisation of the PRT-shaded
  object and its shadow plane with a virtual camera matching the colour camera (the numba backend,
  the default).
- :mod:`rgbd_envmap.render.gl`: the pyrender / EGL backend (the reference), :func:`egl_available`.
- :mod:`rgbd_envmap.render.layer`: :class:`Layer`, what a render produces.
- :mod:`rgbd_envmap.render.camera`: the checked inputs of a render call and their projection.
- :mod:`rgbd_envmap.render.composite`: :func:`composite`, the layer drawn over the frame in linear
  light, with the exact 8-bit sRGB encoder.

Importing this package imports no OpenGL and sets no environment variable.
"""

from rgbd_envmap.render.composite import composite
from rgbd_envmap.render.gl import egl_available
from rgbd_envmap.render.layer import Layer, RendererUnavailableError
from rgbd_envmap.render.raster import BACKENDS, Renderer

__all__ = [
    "BACKENDS",
    "Layer",
    "Renderer",
    "RendererUnavailableError",
    "composite",
    "egl_available",
]
