"""Real spherical harmonics of the environment map (paper 003 §7.1).

- :mod:`rgbd_envmap.sh.basis`: the real SH basis (Condon–Shortley phase, index k = l(l + 1) + m,
  any number of bands), its Legendre part, the clamped-cosine band factors and Lambertian
  irradiance.
- :mod:`rgbd_envmap.sh.projection`: SH coefficients of an equirect radiance map, with the
  missing-pixel fill (stage 8), for interleaved (H, W, 3) and planar (3, H, W) storage.
- :mod:`rgbd_envmap.sh.incremental`: :class:`IncrementalProjection`, coefficients that follow the
  map's updates through its change log.
- :mod:`rgbd_envmap.sh.bands`: band selection, the fewest bands that shade an object within a
  tolerance.

Coefficient arrays are (n², 3) float64, linear RGB. Conventions: docs/reference/conventions.md;
the algorithms and their accuracy: docs/design/sh.md. Plain-numpy statements of what the compiled
parts compute: :mod:`rgbd_envmap.reference.sh_fill` and :mod:`rgbd_envmap.reference.sh_projection`.
"""

from rgbd_envmap.sh.bands import BandSelection, TransferGram, select_bands, transfer_gram
from rgbd_envmap.sh.basis import MAX_BANDS, basis, check_bands, irradiance, lambertian_band_factors, legendre, n_bands
from rgbd_envmap.sh.incremental import IncrementalProjection
from rgbd_envmap.sh.projection import (
    FILL_RADIUS_PX,
    FillPlan,
    fill_missing,
    fill_plan,
    project_equirect,
    project_planar,
)

__all__ = [
    "FILL_RADIUS_PX",
    "BandSelection",
    "FillPlan",
    "IncrementalProjection",
    "TransferGram",
    "basis",
    "check_bands",
    "MAX_BANDS",
    "fill_missing",
    "fill_plan",
    "irradiance",
    "lambertian_band_factors",
    "legendre",
    "n_bands",
    "project_equirect",
    "project_planar",
    "select_bands",
    "transfer_gram",
]
