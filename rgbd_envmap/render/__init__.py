"""Rendering the virtual object into the live colour frame (paper 003 §7.2; docs/design/render.md).

- :mod:`rgbd_envmap.render.raster`: :class:`Renderer`, offscreen rasterisation of the PRT-shaded
  object and its shadow plane with a virtual camera matching the colour camera (the numba backend,
  the default).
- :mod:`rgbd_envmap.render.gl`: the pyrender / EGL backend (the reference), :func:`egl_available`.
- :mod:`rgbd_envmap.render.layer`: :class:`Layer`, what a render produces.
- :mod:`rgbd_envmap.render.camera`: the checked inputs of a render call and their projection.
- :mod:`rgbd_envmap.render.composite`: :func:`composite`, the layer drawn over the frame in linear
  light, with the exact 8-bit sRGB encoder; :func:`composite_differential`, the differential
  composite over the real geometry.
- :mod:`rgbd_envmap.render.geometry`: :func:`~rgbd_envmap.render.geometry.receiver_mesh`, the real
  surfaces near the object from the map's depth.
- :mod:`rgbd_envmap.render.differential`: lights + SH shading with and without the object, its
  shadow rays and occlusion (:class:`~rgbd_envmap.render.differential.DifferentialShader`).

Importing this package imports no OpenGL and sets no environment variable.
"""

from rgbd_envmap.render.composite import COMPOSITE_MODES, composite, composite_differential
from rgbd_envmap.render.gl import egl_available
from rgbd_envmap.render.layer import Layer, RendererUnavailableError
from rgbd_envmap.render.raster import BACKENDS, Renderer

__all__ = [
    "BACKENDS",
    "COMPOSITE_MODES",
    "Layer",
    "Renderer",
    "RendererUnavailableError",
    "composite",
    "composite_differential",
    "egl_available",
]
