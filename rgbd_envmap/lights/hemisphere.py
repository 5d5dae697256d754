"""The equal-area mapping between the unit square and a hemisphere that the Hemigon sampler uses.

Our reading of Havran, Dmitriev and Seidel's goniometric-diagram mapping: the square [−1, 1]² goes to
the unit disk by the concentric (Shirley–Chiu) map, and the disk to the hemisphere z ≥ 0 by the
Lambert equal-area projection, d = (x √(2 − r²), y √(2 − r²), 1 − r²). Both steps preserve area, so
every cell of an S × S grid on the square covers the same solid angle, 2π / S², and the map is
continuous over the whole square: no seam at φ = 0 and no singular pole, unlike latitude–longitude.
The full sphere is two such squares: the upper hemisphere (z ≥ 0) and the lower one, mirrored in z.

References:
    - Havran, Dmitriev, Seidel: Goniometric Diagram Mapping for Hemisphere, Eurographics 2003 short
      presentations (the equal-area, continuous square–hemisphere mapping).
    - Nikodým, Havran, Bittner (paper 002) §3.1 (its use by the Hemigon sampler).
"""

from __future__ import annotations

import numpy as np

__all__ = ["square_to_hemisphere", "hemisphere_to_square", "CELL_SOLID_ANGLE_SCALE"]

#: a cell of an S × S grid covers CELL_SOLID_ANGLE_SCALE / S² steradians (2π over the square).
CELL_SOLID_ANGLE_SCALE = 2.0 * np.pi

_Q = np.pi / 4.0


def square_to_hemisphere(ab: np.ndarray) -> np.ndarray:
    """(..., 2) points of [−1, 1]² → (..., 3) float64 unit directions with z ≥ 0."""
    ab = np.asarray(ab, np.float64)
    a, b = ab[..., 0], ab[..., 1]
    big_a = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(big_a, a, b)
        t = np.where(big_a, _Q * (b / a), 2.0 * _Q - _Q * (a / b))
    t = np.where(r == 0, 0.0, t)
    x, y = r * np.cos(t), r * np.sin(t)
    rr = np.minimum(x * x + y * y, 1.0)
    s = np.sqrt(2.0 - rr)
    return np.stack([x * s, y * s, 1.0 - rr], axis=-1)


def hemisphere_to_square(d: np.ndarray) -> np.ndarray:
    """Inverse of :func:`square_to_hemisphere`: (..., 3) unit directions (z ≥ 0; for z < 0 the
    mirror −z is used, which gives the lower hemisphere's square) → (..., 2) float64 in [−1, 1]²."""
    d = np.asarray(d, np.float64)
    x, y, z = d[..., 0], d[..., 1], np.abs(d[..., 2])
    rr = np.clip(1.0 - z, 0.0, 1.0)
    rho = np.sqrt(rr)  # disk radius
    h = np.hypot(x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        cx, cy = np.where(h > 0, x / h * rho, 0.0), np.where(h > 0, y / h * rho, 0.0)
        big_x = np.abs(cx) >= np.abs(cy)
        a_big = np.sign(cx) * rho
        b_big = a_big * np.arctan(cy / cx) / _Q
        b_sml = np.sign(cy) * rho
        a_sml = b_sml * np.arctan(cx / cy) / _Q
    a = np.where(big_x, a_big, a_sml)
    b = np.where(big_x, b_big, b_sml)
    a = np.where(rho == 0, 0.0, a)
    b = np.where(rho == 0, 0.0, b)
    return np.clip(np.stack([a, b], axis=-1), -1.0, 1.0)
