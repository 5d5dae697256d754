"""Lights from an environment map: importance sampling of an equirect map into directional (or,
with its depth, point) lights; merging lights of several cameras; the direct / indirect split.

- :func:`sample_lights` with ``method`` ``"pharr"``, ``"hemigon"`` or ``"q2tree"`` (paper 002 §3),
  or ``"val"`` (virtual area lights, paper 000 §4.3), returning a :class:`LightSet`;
  :class:`HemigonState`, :class:`Q2TreeState`, :class:`AreaLightState` carry a method's state from
  frame to frame.
- :func:`merge_lights`: lights of several cameras into one set (paper 002 §4).
- :func:`split_direct_indirect`: the brightest part of a map for lights, the rest for SH (paper 000
  §4.2); :func:`direct_mask` the direct pixels alone, :func:`direct_part` with their SH coefficients.
- :func:`irradiance`: what a light set gives on a surface; :func:`map_integral`: ∫ L dω of a map.

Design, speed and accuracy: docs/design/lights.md. Readable references of each method's core:
:mod:`rgbd_envmap.reference.lights`.

References:
    - Nikodým, Havran, Bittner: Multiple Live Video Environment Map Sampling (paper 002) §3–4.
    - Rohmer, Büschel, Dachselt, Grosch (paper 000) §4.2–4.3.
"""

from rgbd_envmap.lights.areas import AreaLightState
from rgbd_envmap.lights.hemigon import HemigonState
from rgbd_envmap.lights.maps import map_integral
from rgbd_envmap.lights.merge import merge_lights
from rgbd_envmap.lights.q2tree import Q2TreeState
from rgbd_envmap.lights.result import LightSet, irradiance
from rgbd_envmap.lights.sample import MAX_LIGHTS, METHODS, sample_lights
from rgbd_envmap.lights.split import DirectIndirect, direct_mask, direct_part, light_grid, split_direct_indirect

__all__ = ["AreaLightState", "DirectIndirect", "HemigonState", "LightSet", "MAX_LIGHTS", "METHODS", "Q2TreeState", "direct_mask", "direct_part",
           "light_grid", "irradiance", "map_integral", "merge_lights", "sample_lights", "split_direct_indirect"]
