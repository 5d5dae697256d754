"""The input checks every light sampler shares, and the quantities they are judged by.

A light sampler reads an equirect radiance map (docs/reference/conventions.md: row 0 is the zenith,
column 0 starts at the seam φ = −π, +z up), an optional ``valid`` mask and optionally the map's
Euclidean distances ``depth_m`` with the map's world ``origin``. :func:`check_inputs` turns them into
a :class:`MapInputs` (no copy of a C-contiguous float32 / float64 map). The values the samplers
cannot check cheaply before their one pass over the map (NaN, negative radiance) are checked by that
pass and reported through :func:`raise_bad_values`.

:func:`map_integral` is the quantity the lights' power adds up to: ∫ L dω as Σ over valid pixels of
L × the pixel's exact solid angle.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rgbd_envmap.checks import check_array, check_finite
from rgbd_envmap.errors import InvalidInputError, NonFiniteError, RangeError, ShapeError
from rgbd_envmap.geometry import equirect_solid_angles

__all__ = ["LUMINANCE_WEIGHTS", "MapInputs", "check_inputs", "map_integral", "luminance", "raise_bad_values"]

#: Rec. 709 luminance of linear RGB (the weights :mod:`rgbd_envmap.prt` uses too).
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)


class MapInputs(NamedTuple):
    """A checked map. ``radiance`` (H, W, 3) C-contiguous float32 or float64; ``valid`` (H, W) bool
    or None (every pixel); ``depth_m`` (H, W) C-contiguous float or None; ``origin`` (3,) float64
    (zeros without depth); ``row_omega`` (H,) float64 the solid angle of a pixel in each row."""

    radiance: np.ndarray
    valid: np.ndarray | None
    depth_m: np.ndarray | None
    origin: np.ndarray
    row_omega: np.ndarray


def check_inputs(radiance: object, valid: object = None, depth_m: object = None, origin: object = None) -> MapInputs:
    """Check a map for the samplers: shapes, dtypes, size, at least one valid pixel, finite depth at
    valid pixels. Radiance values are checked by the sampler's pass (:func:`raise_bad_values`)."""
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    H, W = rad.shape[:2]
    if H == 0 or W == 0:
        raise ShapeError(f"radiance: expected a non-empty map, got {H}×{W} pixels")
    row_omega = np.ascontiguousarray(equirect_solid_angles(H, W)[:, 0])  # also bounds the size
    if rad.dtype not in (np.float32, np.float64):
        rad = rad.astype(np.float32 if rad.dtype.itemsize < 8 or rad.dtype.kind in "iu" else np.float64)
    rad = np.ascontiguousarray(rad)
    if valid is not None:
        valid = np.ascontiguousarray(check_array(valid, "valid", shape=(H, W), dtype="bool"))
        if not valid.any():
            raise InvalidInputError(f"valid: expected at least one valid pixel, got none of {H * W}")
    if depth_m is None:
        if origin is not None:
            raise InvalidInputError("origin: given without depth_m; a map's origin places lights only with its depth")
        org = np.zeros(3)
    else:
        dep = check_array(depth_m, "depth_m", shape=(H, W), dtype=("float", "int"))
        dep = np.ascontiguousarray(dep, dtype=np.float64 if dep.dtype == np.float64 else np.float32)
        check_finite(dep if valid is None else dep[valid], "depth_m" + ("" if valid is None else " (at valid pixels)"))
        if (dep if valid is None else dep[valid]).min() < 0:
            raise RangeError("depth_m: expected distances ≥ 0 at valid pixels, got "
                             f"{(dep if valid is None else dep[valid]).min()}")
        depth_m = dep
        org = check_array((0.0, 0.0, 0.0) if origin is None else origin, "origin", shape=(3,),
                          dtype=("float", "int"), finite=True).astype(np.float64)
    return MapInputs(rad, valid, depth_m, org, row_omega)


def raise_bad_values(inputs: MapInputs, lowest: float, finite: bool) -> None:
    """Raise :class:`NonFiniteError` / :class:`RangeError` if a sampler's pass saw a NaN or infinite
    value, or a negative one, at a valid pixel; else return."""
    where = "" if inputs.valid is None else " (at valid pixels)"
    if not finite:
        vals = inputs.radiance if inputs.valid is None else inputs.radiance[inputs.valid]
        check_finite(vals, "radiance" + where)
        raise NonFiniteError("radiance: the sums overflowed float64; scale the map down")
    if lowest < 0:
        raise RangeError(f"radiance: expected values ≥ 0{where}, got a smallest value of {lowest}")


def luminance(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB → (...) float64 Rec. 709 luminance."""
    w = LUMINANCE_WEIGHTS
    rgb = np.asarray(rgb, np.float64)
    return w[0] * rgb[..., 0] + w[1] * rgb[..., 1] + w[2] * rgb[..., 2]


def map_integral(radiance: object, valid: object = None) -> np.ndarray:
    """(3,) float64 ∫ L dω: Σ over valid pixels (every pixel when ``valid`` is None) of the radiance
    times the pixel's exact solid angle. NaN or infinity at a valid pixel raises NonFiniteError."""
    m = check_inputs(radiance, valid)
    rad = m.radiance.astype(np.float64)
    if m.valid is not None:
        rad = np.where(m.valid[..., None], rad, 0.0)
    check_finite(rad, "radiance" + ("" if m.valid is None else " (at valid pixels)"))
    return np.einsum("hwc,h->c", rad, m.row_omega)
