"""Compositing a rendered :class:`~rgbd_envmap.render.layer.Layer` over the live colour frame
(paper 003 §7.2; docs/design/overview.md, stage 10).

:func:`composite` maps the object's colours from the reference colour space into the current
frame's by the inverse of the latest accepted correction matrix, clips and sRGB-encodes them and
draws them over the frame; the shadow plane is a dark-grey plane alpha-blended **in linear light**
(docs/design/render.md explains the choice). The 8-bit encoding is exact (round half up of
255 · srgb(x) in float64) by a lookup table (:func:`srgb8_encoder`). The per-pixel loop is in
:mod:`rgbd_envmap._kernels.composite`; the same in plain numpy:
:func:`rgbd_envmap.reference.render_composite.composite`.

References:
    Monroy, Hudon, Smolic (2018), Dynamic Environment Mapping for Augmented Reality Applications on
    Mobile Devices, §7.1 (dark-grey shadow plane with alpha from the irradiance ratio) and §7.2
    (compositing with the inverse correction matrix).
    IEC 61966-2-1:1999 (sRGB transfer function).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from rgbd_envmap._kernels import composite as kernels
from rgbd_envmap._kernels import differential as diff_kernels
from rgbd_envmap.checks import check_array
from rgbd_envmap.colour import srgb8_to_linear_lut, srgb_to_linear
from rgbd_envmap.errors import DTypeError, NonFiniteError, RangeError, RgbdEnvmapError, ShapeError
from rgbd_envmap.render.layer import Layer

__all__ = ["COMPOSITE_MODES", "RATIO_EPS", "composite", "composite_differential", "srgb8_encoder"]

#: the differential composite leaves a receiver pixel as it is where its ratio E_with / E_without is
#: within this of 1 in every channel (so triangles whose vertices all are need not be drawn).
RATIO_EPS = diff_kernels.RATIO_EPS

#: the composite modes of the pipeline (``render.composite``): ``"paper003"``, the PRT-shaded object and
#: the shadow plane's alpha (:func:`composite`); ``"differential"``, the object and its change to the
#: real surfaces from the map's depth, lit by lights + SH (:func:`composite_differential`,
#: docs/design/differential.md).
COMPOSITE_MODES = ("paper003", "differential")

ENCODE_BINS = kernels.ENCODE_BINS


@lru_cache(maxsize=1)
def srgb8_encoder() -> tuple[np.ndarray, np.ndarray]:
    """The (read-only, cached) tables of the exact 8-bit sRGB encoder of :func:`composite`.

    ``thresholds`` (256,) float64 holds the 255 linear values at which the code steps up, then +inf,
    so code(x) = #{t_k ≤ x} = round-half-up(255 · srgb(x)) (evaluated in float64); ``base``
    (ENCODE_BINS,) uint8 is that count at each bin's lower edge. Consecutive thresholds are at least
    3.0e-4 apart (at the dark end) > 1/4096, so a bin holds at most one step: the code of x is
    ``base[bin] + (x ≥ thresholds[base[bin]])``."""
    t = srgb_to_linear((np.arange(1, 256, dtype=np.float64) - 0.5) / 255.0)
    if np.diff(t).min() <= 1.0 / ENCODE_BINS:  # a guard on the reasoning above, not on user input
        raise RgbdEnvmapError("sRGB encoder table: bins too coarse")
    base = np.searchsorted(t, np.arange(ENCODE_BINS) / ENCODE_BINS, side="right").astype(np.uint8)
    t = np.append(t, np.inf)
    for a in (t, base):
        a.setflags(write=False)
    return t, base


def composite(frame_srgb: np.ndarray, layer: Layer, *, ccm_inverse: np.ndarray | None = None,
              shadow_grey: float = 0.15) -> np.ndarray:
    """Draw a rendered :class:`Layer` over a live colour frame (paper 003 §7.2).

    The object's colours are in the reference colour space; ``ccm_inverse`` (the inverse of the latest
    accepted correction matrix, :func:`rgbd_envmap.colour.invert_ccm`) maps them into this frame's
    space (``dst = rgb @ ccm_inverse.T``, :func:`rgbd_envmap.colour.apply_ccm`'s convention). They are
    then clipped to [0, 1], sRGB-encoded and written where ``layer.mask`` is set. Where the shadow
    plane is visible the frame is blended towards a grey plane, **in linear light**:
    ``out = (1 − α) · frame + α · grey`` with ``frame`` decoded from sRGB and ``grey`` =
    ``ccm_inverse @ (shadow_grey, shadow_grey, shadow_grey)`` (the plane is virtual content in the
    reference space, like the object). With ``shadow_grey = 0`` this is the physical attenuation
    ``frame · (1 − α)``; docs/design/render.md explains why not in sRGB. 8-bit codes round half up.

    Args:
        frame_srgb: (H, W, 3) uint8 sRGB, the live colour frame (not modified).
        layer: a :class:`Layer` of the same (H, W).
        ccm_inverse: (3, 3) finite float, or None for the identity (frame space = reference space).
        shadow_grey: linear grey level of the shadow plane in the reference space, ≥ 0.

    Returns:
        (H, W, 3) uint8 sRGB, a new array; equal to ``frame_srgb`` bit for bit where the layer is empty.
    """
    frame, grey_level, m, use_m = _checked_inputs(frame_srgb, {"layer": layer}, ccm_inverse, shadow_grey)
    out = frame.copy()
    if layer.bbox is None:
        return out
    grey = m @ np.full(3, grey_level)
    r0, r1, c0, c1 = layer.bbox
    kernels.composite(out, layer.colour, layer.mask, layer.plane_alpha, r0, r1, c0, c1, m, use_m, grey,
                      srgb8_to_linear_lut(), *srgb8_encoder())
    return out


def _checked_inputs(frame_srgb, layers: dict, ccm_inverse, shadow_grey) -> tuple[np.ndarray, float, np.ndarray, bool]:
    """The composites' checks: (frame, grey level, ccm_inverse as float64 (identity if None), given)."""
    frame = check_array(frame_srgb, "frame_srgb", shape=("H", "W", 3), dtype=np.uint8)
    for name, lay in layers.items():
        if not isinstance(lay, Layer):
            raise DTypeError(f"{name}: expected a Layer, got {type(lay).__name__}")
        if frame.shape[:2] != lay.shape:
            raise ShapeError(f"{name}: expected the frame's size {frame.shape[:2]}, got {lay.shape}")
    grey_level = float(shadow_grey)
    if not np.isfinite(grey_level) or grey_level < 0.0:
        raise RangeError(f"shadow_grey: expected a finite value >= 0, got {shadow_grey}")
    if ccm_inverse is None:
        return frame, grey_level, np.eye(3), False
    m = check_array(ccm_inverse, "ccm_inverse", shape=(3, 3), dtype=("float", "int"), finite=True)
    return frame, grey_level, np.ascontiguousarray(m, dtype=np.float64), True


def composite_differential(frame_srgb: np.ndarray, object_layer: Layer, receiver_layer: Layer, *,
                           ccm_inverse: np.ndarray | None = None, shadow_grey: float = 0.15) -> np.ndarray:
    """Differential composite (papers 000 §5, 001 §3.1; docs/design/differential.md).

    ``object_layer``: the rendered object (colours in the reference space) and the shadow plane's
    alpha; ``receiver_layer``: the real surfaces near the object, rendered with their per-vertex ratio
    E_with / E_without (reference space) as colour. Per pixel: the object's colour mapped by
    ``ccm_inverse`` where the object is; where a receiver is, the frame in linear light times the
    ratio in the reference space, ``M⁻¹ (ratio ⊙ (M · frame))`` (M = the correction matrix, the
    inverse of ``ccm_inverse``; the frame's radiance · E_with / E_without, i.e. camera +
    albedo · (E_with − E_without) / π with albedo = π · camera / E_without); elsewhere the paper-003
    plane blend of :func:`composite` (the fallback where the map has no geometry). Same 8-bit encoding
    as :func:`composite`; the same codes as
    :func:`rgbd_envmap.reference.render_differential.composite_differential`.

    Returns:
        (H, W, 3) uint8 sRGB, a new array; equal to ``frame_srgb`` where both layers are empty.
    """
    frame, grey_level, m_inv, use_m = _checked_inputs(
        frame_srgb, {"object_layer": object_layer, "receiver_layer": receiver_layer}, ccm_inverse, shadow_grey)
    m = np.linalg.inv(m_inv) if use_m else m_inv
    if not np.isfinite(m).all():
        raise NonFiniteError("ccm_inverse: expected an invertible matrix")
    out = frame.copy()
    boxes = [b for b in (object_layer.bbox, receiver_layer.bbox) if b is not None]
    if not boxes:
        return out
    r0, r1 = min(b[0] for b in boxes), max(b[1] for b in boxes)
    c0, c1 = min(b[2] for b in boxes), max(b[3] for b in boxes)
    grey = m_inv @ np.full(3, grey_level)
    diff_kernels.composite_differential(out, object_layer.colour, object_layer.mask, object_layer.plane_alpha,
                                        receiver_layer.colour, receiver_layer.mask, r0, r1, c0, c1, m, m_inv,
                                        use_m, grey, srgb8_to_linear_lut(), *srgb8_encoder())
    return out
