"""The one entry point of the light samplers: :func:`sample_lights` (method dispatch, checks, and
placing the lights with the map's depth).

References:
    - Nikodým, Havran, Bittner (paper 002) §3 (the three samplers, each after its source).
    - Rohmer et al. (paper 000) §4.3 (lights placed where the map's surfaces are, not at infinity;
      virtual area lights).
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap.checks import check_method, check_number
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.lights.areas import area_samples
from rgbd_envmap.lights.hemigon import hemigon_samples
from rgbd_envmap.lights.maps import check_inputs
from rgbd_envmap.lights.pharr import pharr_samples
from rgbd_envmap.lights.q2tree import q2tree_samples
from rgbd_envmap.lights.result import LightSet

__all__ = ["METHODS", "MAX_LIGHTS", "sample_lights"]

#: the samplers and the options each takes.
METHODS = {"pharr": (), "hemigon": ("side",), "q2tree": ("a", "b", "jitter", "level"), "val": ("points", "iterations")}
#: the most lights one call makes.
MAX_LIGHTS = 1_000_000


def sample_lights(radiance: object, n: int, method: str = "q2tree", valid: object = None, *,
                  depth_m: object = None, origin: object = None, state: object = None, **options) -> LightSet:
    """Sample n lights from an equirect radiance map.

    Args:
        radiance: (H, W, 3) float linear radiance (docs/reference/conventions.md); values ≥ 0 at
            valid pixels; NaN is allowed under ``valid = False``.
        n: lights asked for, 1 … 1 000 000. ``"pharr"`` and ``"hemigon"`` give exactly n;
            ``"q2tree"`` gives 12 + 3k ≥ n (n rounded up to a tree's leaf count, at least 12);
            ``"val"`` gives at most n (the clusters that hold a pixel).
        method: ``"pharr"`` (luminance × solid angle PDF, Halton points), ``"hemigon"`` (equal-area
            hemisphere squares, temporal filters through ``state``), ``"q2tree"`` (HEALPix quad tree,
            incremental through ``state``), ``"val"`` (virtual area lights, paper 000 §4.3: the
            map's points clustered by position, each cluster a light on its surface with ``points``
            spread over its area; needs ``depth_m``; warm-started through ``state``). Unknown names
            raise UnknownMethodError listing these.
        valid: (H, W) bool or None (every pixel); at least one pixel must be valid.
        depth_m: (H, W) Euclidean distance of the map's surfaces from ``origin`` (metres), or None.
            With it, every light gets a world position: the distance of its pixel (PDF methods) or
            the luminance-power-weighted mean distance of its quad (Q2-Tree) along its direction.
        origin: (3,) world position of the map's centre (default 0), only with ``depth_m``.
        state: a :class:`~rgbd_envmap.lights.HemigonState`,
            :class:`~rgbd_envmap.lights.Q2TreeState` or :class:`~rgbd_envmap.lights.AreaLightState`
            fed frame after frame, or None.
        **options: ``side`` (hemigon: cells per square side), ``a``, ``b`` (q2tree: importance
            exponents, 1 and 1/4), ``jitter`` (q2tree: deterministic jitter of the light in its quad),
            ``level`` (q2tree: the finest level, deepest quads nside = 2^level; default: quads of
            about 4 pixels or more, deeper if n needs it); ``points`` (val: area points per light,
            8), ``iterations`` (val: the most k-means iterations, 20).

    Returns:
        A :class:`LightSet`.

    Example:
        >>> import numpy as np
        >>> from rgbd_envmap.lights import sample_lights
        >>> lights = sample_lights(np.ones((32, 64, 3), np.float32), 200)
        >>> len(lights), bool(np.allclose(lights.total_power, 4 * np.pi))
        (201, True)
    """
    check_method(method, METHODS)
    n = check_number(n, "n", low=1, high=MAX_LIGHTS, integer=True)
    bad = sorted(set(options) - set(METHODS[method]))
    if bad:
        raise InvalidInputError(f"options: {bad} not taken by method {method!r}; it takes {list(METHODS[method])}")
    inputs = check_inputs(radiance, valid, depth_m, origin)
    solid_angle = cells = dist = None
    if method == "val":
        d, power, solid_angle, positions, pts, pts_power = area_samples(inputs, n, state, **options)
        return LightSet(d, power, method, solid_angle=solid_angle, positions=positions, origin=inputs.origin,
                        points=pts, point_power=pts_power)
    if method == "pharr":
        if state is not None:
            raise InvalidInputError(f"state: method 'pharr' keeps no state, got {type(state).__name__}")
        d, power, rows, cols = pharr_samples(inputs, n)
        if inputs.depth_m is not None:
            dist = inputs.depth_m[rows, cols].astype(np.float64)
    elif method == "hemigon":
        d, power, _, dist = hemigon_samples(inputs, n, state, **options)
    else:
        d, power, solid_angle, dist, cells = q2tree_samples(inputs, n, state, **options)
    positions = origin_out = None
    if dist is not None:
        positions = inputs.origin + d * dist[:, None]
        origin_out = inputs.origin
    return LightSet(d, power, method, solid_angle=solid_angle, positions=positions, origin=origin_out, cells=cells)
