"""SH projection of equirect radiance maps, with the missing-pixel fill (paper 003 §7.1, stage 8).

What is computed: L_k = Σ_p Y_k(d_p) radiance_p Ω_p over the pixels p of an equirect map, with d_p
the pixel-centre direction and Ω_p its exact solid angle (docs/reference/conventions.md), Y_k the
real SH of :mod:`rgbd_envmap.sh.basis`, and missing pixels filled first.

Missing pixels (docs/design/overview.md, stage 8): a pixel with ``valid = False`` takes the
radiance of the closest data pixel along the 4-connected directions (up, down, left, right) within
``fill_radius_px`` (50) pixels. Longitude wraps across the seam; rows do not wrap across the poles.
Ties at the same distance are broken in the fixed order up, down, left, right. A pixel with no data
pixel within that distance in any of the four directions is skipped (contributes nothing). The rule
in plain numpy: :mod:`rgbd_envmap.reference.sh_fill`.

How: the projection is separable. Y_k at pixel (v, u) is a row factor (the Legendre part, depends on
v) times a column factor (cos(mφ_u) or sin(|m|φ_u)). So each row is first reduced to its 2n − 1
longitude sums (float32, one row at a time, in a numba kernel that folds the four columns sharing
|cos mφ|, |sin mφ|: :mod:`rgbd_envmap._kernels.sh_projection`), and the rows are then combined in
float64 with the Legendre weights times the exact row solid angle. The fill is planned once from the
mask (:func:`fill_plan`) and applied while each row is staged, so no filled copy is written. The
tables depend only on (H, W, bands) and are cached (:func:`projection_tables`). Planar (3, H, W)
storage (``EnvironmentMap``) is read in place. docs/design/sh.md describes the algorithm and its
cost. The same sums in plain numpy: :mod:`rgbd_envmap.reference.sh_projection`.

Invalid input: NaN or infinity in the radiance at a pixel that contributes (valid pixels, or every
pixel when ``valid`` is None) raises :class:`NonFiniteError`. Values under ``valid = False`` are
never used except as fill sources (which are valid by definition), so they may be NaN. An empty map
(H or W = 0) raises :class:`ShapeError`; a map with no data at all gives zero coefficients. Wrong
shapes raise :class:`ShapeError`; bad ``bands`` or ``fill_radius_px`` raise :class:`RangeError` /
:class:`DTypeError`.

References:
    - Paper 003 §7.1 (25 coefficients per channel from the EM; filling of missing EM pixels).
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from rgbd_envmap._kernels import sh_fill, sh_projection
from rgbd_envmap.checks import check_array, check_finite, check_finite_where, check_positive_int
from rgbd_envmap.errors import NonFiniteError, RangeError, ShapeError
from rgbd_envmap.geometry import MAX_EQUIRECT_PIXELS, equirect_solid_angles
from rgbd_envmap.sh.basis import check_bands, legendre

__all__ = [
    "FILL_RADIUS_PX",
    "FillPlan",
    "ProjectionTables",
    "check_map_size",
    "fill_missing",
    "fill_plan",
    "project_equirect",
    "project_planar",
    "project_with_plan",
    "projection_tables",
    "raise_non_finite",
]

FILL_RADIUS_PX = 50
"""Largest distance, in pixels along one of the 4 directions, from which a missing EM pixel is filled
(docs/design/overview.md, stage 8)."""

#: Fill key of a missing pixel without a source (keys rank sources: 4 · distance + direction).
NO_KEY = sh_fill.NO_KEY
#: Orders m per pass of the projection kernel's row sums.
BLOCK = sh_projection.BLOCK


# --- the fill plan -----------------------------------------------------------------------------------

class FillPlan(NamedTuple):
    """The missing pixels of a mask, row by row, and the data pixel each copies (:func:`fill_plan`).

    Attributes:
        row_ptr: (H + 1,) int64; the missing pixels of row v are ``col[row_ptr[v]:row_ptr[v + 1]]``.
        col: (n,) int32 their columns, increasing within a row.
        src: (n,) int64 the flat index v' W + u' of the data pixel each copies, or −1 (none within
            the radius: the pixel is skipped).
        empty: (H,) bool, True for a row that contributes nothing (no pixel has or gets data).
        key: (n,) int32 the rank of each source, 4 · distance + direction (0 up, 1 down, 2 left,
            3 right), the order in which the rule prefers sources; :data:`NO_KEY` without a source.
    """

    row_ptr: np.ndarray
    col: np.ndarray
    src: np.ndarray
    empty: np.ndarray
    key: np.ndarray


def _plan(valid: np.ndarray, radius_px: int) -> FillPlan:
    H, W = valid.shape
    if W % 8:
        valid = np.pad(valid, ((0, 0), (0, 8 - W % 8)), constant_values=True)
    b = np.ascontiguousarray(valid).view(np.uint8)
    return FillPlan(*sh_fill.fill_plan(b, b.view(np.uint64), H, W, radius_px))


def fill_plan(valid: np.ndarray, radius_px: int = FILL_RADIUS_PX) -> FillPlan:
    """Plan the fill of the missing pixels (``valid = False``) of an (H, W) bool mask: which data
    pixel each one copies under the rule of the module docstring, within ``radius_px`` pixels.

    One pass over the mask, 8 pixels at a time, then O(1) per missing pixel (a missing polar cap
    costs no 50-step search per pixel)."""
    valid = check_array(valid, "valid", shape=("H", "W"), dtype="bool")
    return _plan(valid, check_positive_int(radius_px, "radius_px"))


def fill_missing(radiance: np.ndarray, valid: np.ndarray, radius_px: int = FILL_RADIUS_PX
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Fill missing EM pixels from the closest data pixel along up / down / left / right.

    :func:`project_equirect` applies the same rule row by row without building this filled copy;
    this function is for looking at the result.

    Args:
        radiance: (H, W, 3) float linear radiance; values under ``valid = False`` are not used (NaN
            is fine there).
        valid: (H, W) bool, True where the EM has data.
        radius_px: largest search distance in pixels (50 in the paper).

    Returns:
        (filled (H, W, 3) float32, used (H, W) bool). ``used`` is False for pixels with no data pixel
        within ``radius_px`` in any of the 4 directions; their ``filled`` value is 0. Longitude wraps;
        rows do not cross the poles; equal distances prefer up, down, left, right in that order.
    """
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    valid = check_array(valid, "valid", shape=rad.shape[:2], dtype="bool")
    check_finite_where(rad, valid, "radiance", "valid")
    radius_px = check_positive_int(radius_px, "radius_px")
    row_ptr, col, src, _, _ = _plan(valid, radius_px)
    out = rad.astype(np.float32, order="C")  # a copy; its missing pixels are overwritten below
    used = np.ones(rad.shape[:2], bool)
    sh_fill.apply_fill(rad, row_ptr, col, src, out, used)
    return out, used


# --- the projection ----------------------------------------------------------------------------------

class ProjectionTables(NamedTuple):
    """Read-only tables of the projection of an H × W map to n bands (:func:`projection_tables`).

    Attributes:
        tcb, tsb: (nblocks, 5, L) float32 cos(mφ), sin(mφ) for m = 5j + i (zero for m ≥ bands), at
            the first quarter of the columns (L = W/4, ``folded``) or at every column (L = W).
        folded: W % 4 == 0: the kernel folds the four columns that share |cos mφ|, |sin mφ|.
        row_w: (H, n²) float64, the Legendre part of Y_k at each row (incl. sin^|m| θ and √2) times
            the exact solid angle of one pixel of that row.
        m_abs, m_sin: (n²,) int64, where the row sum used by coefficient k sits: sums[|m|, m < 0].
    """

    tcb: np.ndarray
    tsb: np.ndarray
    folded: bool
    row_w: np.ndarray
    m_abs: np.ndarray
    m_sin: np.ndarray


@lru_cache(maxsize=8)
def projection_tables(height: int, width: int, bands: int) -> ProjectionTables:
    """The cached :class:`ProjectionTables` of an equirect map of ``height`` × ``width`` pixels (they
    depend only on the map size and the bands)."""
    n = check_bands(bands)
    height = check_positive_int(height, "height")
    width = check_positive_int(width, "width")
    if height * width > MAX_EQUIRECT_PIXELS:
        raise RangeError(f"height×width: expected at most {MAX_EQUIRECT_PIXELS:,} pixels, got {height}×{width}")
    folded = width % 4 == 0
    nblocks = -(-n // BLOCK)
    ncols = width // 4 if folded else width
    phi = 2.0 * np.pi * (np.arange(ncols) + 0.5) / width - np.pi
    m = np.arange(nblocks * BLOCK)
    tcb = np.cos(m[:, None] * phi[None, :])
    tsb = np.sin(m[:, None] * phi[None, :])
    tcb[n:] = 0.0
    tsb[n:] = 0.0
    tcb = tcb.astype(np.float32).reshape(nblocks, BLOCK, ncols)
    tsb = tsb.astype(np.float32).reshape(nblocks, BLOCK, ncols)
    theta = np.pi * (np.arange(height) + 0.5) / height
    leg = legendre(np.cos(theta), n)
    m_of_k = np.concatenate([np.arange(-l, l + 1) for l in range(n)])
    leg *= np.sin(theta)[:, None] ** np.abs(m_of_k)[None, :]
    row_w = leg * equirect_solid_angles(height, width)[:, :1]
    m_abs = np.abs(m_of_k).astype(np.int64)
    m_sin = (m_of_k < 0).astype(np.int64)
    for a in (tcb, tsb, row_w, m_abs, m_sin):
        a.setflags(write=False)
    return ProjectionTables(tcb, tsb, folded, row_w, m_abs, m_sin)


def _no_plan(height: int) -> FillPlan:
    """The plan of a map without missing pixels."""
    return FillPlan(np.zeros(height + 1, np.int64), np.zeros(0, np.int32), np.zeros(0, np.int64),
                    np.zeros(height, bool), np.zeros(0, np.int32))


def project_with_plan(data: np.ndarray, planar: bool, plan: FillPlan, bands: int) -> np.ndarray:
    """(n², 3) float64 coefficients of checked, C-contiguous float32 ``data`` ((3, H, W) when
    ``planar``, else (H, W, 3)) filled by ``plan``. No checks: NaN or infinity at a contributing
    pixel gives non-finite coefficients (see :func:`raise_non_finite`)."""
    H, W = data.shape[1:] if planar else data.shape[:2]
    kernel = sh_projection.project_planar if planar else sh_projection.project_interleaved
    return kernel(data, plan.row_ptr, plan.col, plan.src, plan.empty, *projection_tables(H, W, bands))


def raise_non_finite(data: np.ndarray, planar: bool, valid: np.ndarray | None, name: str) -> None:
    """Raise :class:`NonFiniteError` for a projection whose result is not finite: naming the NaN or
    infinity among the contributing pixels, or else the overflow of a sum."""
    where = "" if valid is None else " (at valid pixels)"
    chans = [data[c] if planar else data[..., c] for c in range(3)]
    for ch in chans:
        check_finite(ch if valid is None else ch[valid], name + where)
    raise NonFiniteError(f"{name}: the projection overflowed float32/float64; scale the map down")


def _project(data: np.ndarray, planar: bool, valid: np.ndarray | None, bands: int, radius_px: int,
             name: str = "radiance") -> np.ndarray:
    """``data`` is C-contiguous float32, (3, H, W) when ``planar`` else (H, W, 3); checked already."""
    H = data.shape[1] if planar else data.shape[0]
    plan = _no_plan(H) if valid is None else _plan(valid, radius_px)
    coeffs = project_with_plan(data, planar, plan, bands)
    if not np.isfinite(coeffs).all():  # NaN / inf propagate into the sums (cheap path otherwise)
        raise_non_finite(data, planar, valid, name)
    return coeffs


def check_map_size(H: int, W: int, name: str) -> None:
    """:class:`ShapeError` for an empty (H or W = 0) map."""
    if H == 0 or W == 0:
        raise ShapeError(f"{name}: expected a non-empty map, got {H}×{W} pixels")


def project_equirect(radiance: np.ndarray, valid: np.ndarray | None = None, bands: int = 5, *,
                     fill_radius_px: int = FILL_RADIUS_PX) -> np.ndarray:
    """SH coefficients L_k = Σ_p Y_k(d_p) radiance_p Ω_p of an equirect radiance map.

    Args:
        radiance: (H, W, 3) float linear radiance. Fast paths (no copy): float32 C-contiguous, and
            float32 whose channel axis is outermost in memory, i.e. the (H, W, 3) view of planar
            (3, H, W) storage such as ``EnvironmentMap.radiance``. Anything else is converted to
            float32 first. Directions and exact solid angles follow docs/reference/conventions.md.
        valid: (H, W) bool or None (every pixel has data). Missing pixels are filled by the rule of
            the module docstring (see :func:`fill_missing`); pixels that cannot be filled are
            skipped. A map with no data at all gives zero coefficients.
        bands: number of bands n ≥ 1.
        fill_radius_px: the fill's search radius in pixels (paper: 50).

    Returns:
        (n², 3) float64 coefficients. Row sums over longitude are float32 (relative error ~1e-7),
        rows are combined in float64.

    Raises:
        ShapeError: wrong shapes or an empty map. RangeError / DTypeError: bad ``bands`` or
        ``fill_radius_px``. NonFiniteError: NaN or infinity at a contributing pixel (or a sum that
        overflows).
    """
    bands = check_bands(bands)
    radius_px = check_positive_int(fill_radius_px, "fill_radius_px")
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    H, W = rad.shape[:2]
    check_map_size(H, W, "radiance")
    if valid is not None:
        valid = check_array(valid, "valid", shape=(H, W), dtype="bool")
    planes = rad.transpose(2, 0, 1)
    if rad.dtype == np.float32 and planes.flags.c_contiguous:
        return _project(planes, True, valid, bands, radius_px)
    return _project(np.ascontiguousarray(rad, dtype=np.float32), False, valid, bands, radius_px)


def project_planar(planes: np.ndarray, valid: np.ndarray | None = None, bands: int = 5, *,
                   fill_radius_px: int = FILL_RADIUS_PX) -> np.ndarray:
    """:func:`project_equirect` for planar (3, H, W) radiance (the storage of ``EnvironmentMap``).

    Args:
        planes: (3, H, W) float linear radiance; float32 C-contiguous is used without a copy.
        valid, bands, fill_radius_px: as for :func:`project_equirect`.

    Returns:
        (n², 3) float64 coefficients, identical to ``project_equirect(planes.transpose(1, 2, 0), ...)``.
    """
    bands = check_bands(bands)
    radius_px = check_positive_int(fill_radius_px, "fill_radius_px")
    p = check_array(planes, "planes", shape=(3, "H", "W"), dtype=("float", "int"))
    H, W = p.shape[1:]
    check_map_size(H, W, "planes")
    if valid is not None:
        valid = check_array(valid, "valid", shape=(H, W), dtype="bool")
    return _project(np.ascontiguousarray(p, dtype=np.float32), True, valid, bands, radius_px, "planes")
