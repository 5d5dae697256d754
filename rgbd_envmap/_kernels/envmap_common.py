"""Helpers shared by the map's kernels (update, pairs, translation): selects, map coordinates.

Internal to :mod:`rgbd_envmap._kernels`; the public meaning of the coordinates is in
:func:`rgbd_envmap.geometry.directions_to_equirect` (row 0 at the zenith, pixel centres at k + 0.5).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["ATAN_POLY", "atan2_branchless", "block_coords"]

#: Samples are processed in blocks of this many: their map coordinates are computed for the whole
#: block in one vectorised loop into small buffers that stay in L1.
_BLOCK = 256

#: at 2000×1000 is 3.1e-3 rad), so a point within 1.2e-8 rad of a pixel edge may land next door.
#: :func:`atan2_branchless` writes these coefficients out (tests check it against math.atan2).
ATAN_POLY = (0.9999999842426203, -0.33333066780599485, 0.1999248357706807, -0.1420257050187139, 0.10636754062743976, -0.07495445371631375, 0.04258760664298073, -0.01600503000542798, 0.0028340641752807177)


@numba.njit(cache=True, inline="always")
def _mx(a, b):  # pragma: no cover - compiled
    """max(a, b) with numba's semantics (b if b > a else a), as a select: in large kernels the
    builtin stayed a call, which kept loops from vectorising."""
    return b if b > a else a  # noqa: FURB136 - the point is not to call max()


@numba.njit(cache=True, inline="always")
def _mn(a, b):  # pragma: no cover - compiled
    """min(a, b) with numba's semantics (b if b < a else a), as a select (see :func:`_mx`)."""
    return b if b < a else a  # noqa: FURB136 - the point is not to call min()




@numba.njit(cache=True, inline="always")
def _u(i):  # pragma: no cover - compiled
    """An index as uint64: numba then skips the negative-index wraparound (a select per access that
    doubled the cost of the update's pixel loops)."""
    return np.uint64(i)


@numba.njit(cache=True, fastmath=True, inline="always")
def atan2_branchless(y, x):  # pragma: no cover - compiled
    """atan2 from :data:`ATAN_POLY`, written with selects only so that loops calling it vectorise
    (libm's atan2 is ~40 ns a call and blocks vectorisation)."""
    ax, ay = abs(x), abs(y)
    mx = _mx(ax, ay)
    t = _mn(ax, ay) / (mx if mx > 0.0 else 1.0)
    t2 = t * t
    # ATAN_POLY written out: a loop over the tuple keeps the callers' loops from vectorising.
    p = 0.0028340641752807177
    p = p * t2 + -0.01600503000542798
    p = p * t2 + 0.04258760664298073
    p = p * t2 + -0.07495445371631375
    p = p * t2 + 0.10636754062743976
    p = p * t2 + -0.1420257050187139
    p = p * t2 + 0.1999248357706807
    p = p * t2 + -0.33333066780599485
    p = p * t2 + 0.9999999842426203
    a = t * p
    a = 0.5 * math.pi - a if ay > ax else a
    a = math.pi - a if x < 0.0 else a
    return -a if y < 0.0 else a


@numba.njit(cache=True, fastmath=True)
def block_coords(points, start, m, ox, oy, oz, kv, ku, bx, by, bz, bv, bu, br):  # pragma: no cover - compiled
    """Continuous (v, u) and distance from the origin (ox, oy, oz) of points[start : start + m] into
    the block buffers. The points are copied into structure-of-arrays block buffers first: the
    (N, 3) layout read directly vectorised 3× worse. Branch-free (:func:`atan2_branchless`), so
    it vectorises. Non-finite points give garbage: callers test the points themselves (fastmath may
    fold a finiteness test on the results away)."""
    for j in range(m):
        bx[j] = points[start + j, 0] - ox
        by[j] = points[start + j, 1] - oy
        bz[j] = points[start + j, 2] - oz
    for j in range(m):
        dx, dy, dz = bx[j], by[j], bz[j]
        h = math.sqrt(dx * dx + dy * dy)
        br[j] = math.sqrt(h * h + dz * dz)
        bv[j] = atan2_branchless(h, dz) * kv
        bu[j] = (atan2_branchless(dy, dx) + math.pi) * ku

