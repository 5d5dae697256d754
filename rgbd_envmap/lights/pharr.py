"""The Pharr light sampler: luminance × solid angle as a PDF over equirect pixels, Halton points
through the inverted CDF (paper 002 §3.1, after Pharr and Humphreys).

The weight of pixel (v, u) is Y(L) · Ω_v: its luminance (Rec. 709) times its exact solid angle, the
discrete form of the paper's luminance × sin θ. One pass over the map (a numba kernel,
:mod:`rgbd_envmap._kernels.lights_pharr`) writes the flat CDF in row-major order and checks the
values; the n Halton points (bases 2, 3; the same points every frame, so that lights of two maps
correspond by index) are inverted marginal-then-conditional with continuous offsets inside the pixel
(:func:`rgbd_envmap.lights.cdf.invert_cdf`). Every light carries the same luminance power,
Σ Y·Ω / n, in the colour of its pixel: power = L / Y(L) · Σ Y·Ω / n, so Σ Y(power) = Σ Y·Ω exactly and
each RGB channel's sum is an unbiased estimate of that channel's integral.

A map without energy (every valid pixel black) is sampled by solid angle instead: the lights then
have zero power. The same rule in plain numpy: :func:`rgbd_envmap.reference.lights.pharr`.

References:
    - Pharr, Humphreys: Infinite Area Light Source with Importance Sampling (pbrt plugin, 2004).
    - Nikodým, Havran, Bittner (paper 002) §3.1 and Table 1 ("Pharr").
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap._kernels import lights_pharr
from rgbd_envmap.geometry import equirect_to_directions
from rgbd_envmap.lights.cdf import halton_points, invert_cdf
from rgbd_envmap.lights.maps import LUMINANCE_WEIGHTS, MapInputs, luminance, raise_bad_values

__all__ = ["pharr_samples"]


def pharr_samples(inputs: MapInputs, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sample n lights from a checked map. Returns (directions (n, 3), power (n, 3), rows (n,), cols
    (n,)): the chosen pixels' indices are given for placing the lights with the map's depth."""
    rad = inputs.radiance
    H, W = rad.shape[:2]
    use_valid = inputs.valid is not None
    valid = inputs.valid if use_valid else np.ones((1, 1), bool)
    wr, wg, wb = LUMINANCE_WEIGHTS
    rows_total = np.empty(H)
    lo, finite = lights_pharr.row_totals(rad, valid, use_valid, inputs.row_omega, wr, wg, wb, rows_total)
    raise_bad_values(inputs, lo, finite)
    u = halton_points(n)
    total = float(rows_total.sum())
    if total > 0:
        marginal = np.cumsum(rows_total)
        total = marginal[-1]
        x1 = np.minimum(u[:, 0] * total, np.nextafter(total, -np.inf))
        r = np.searchsorted(marginal, x1, side="right")
        start = marginal[r] - rows_total[r]
        fr = np.clip((x1 - start) / rows_total[r], 0.0, 1.0 - 1e-12)
        order = np.argsort(r, kind="stable")
        c = np.empty(n, np.int64)
        fc = np.empty(n)
        lights_pharr.pick_in_rows(rad, valid, use_valid, inputs.row_omega, wr, wg, wb, order, r, u[:, 1], c, fc)
        col = rad[r, c].astype(np.float64)
        power = col / luminance(col)[:, None] * (total / n)
    else:  # no energy: place the (powerless) lights by solid angle over the valid pixels
        w = np.broadcast_to(inputs.row_omega[:, None], (H, W))
        if use_valid:
            w = w * valid
        r, c, fr, fc = invert_cdf(np.cumsum(w, dtype=np.float64), H, W, u)
        power = np.zeros((n, 3))
    uv = np.stack([c - 0.5 + fc, r - 0.5 + fr], axis=1)
    d = equirect_to_directions(uv, H, W)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d, power, r, c
