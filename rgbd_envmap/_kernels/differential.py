"""Kernel of the differential composite: the object, the real surfaces' ratio E_with / E_without and
the shadow plane's fallback drawn over the frame in linear light.

Called from :mod:`rgbd_envmap.render.composite` only; what it computes, in plain numpy:
:func:`rgbd_envmap.reference.render_differential.composite_differential`.
"""

from __future__ import annotations

import numba
import numpy as np

from rgbd_envmap._kernels.composite import encode8

__all__ = ["RATIO_EPS", "composite_differential"]

#: a receiver pixel whose ratio is within this of 1 in every channel is left as it is (far from the
#: object the ratio is 1 to rounding; an 8-bit code step is at least 0.4 % of the value).
RATIO_EPS = 1e-3


@numba.njit(cache=True)
def composite_differential(out, colour, mask, alpha, ratio, rmask, r0, r1, c0, c1, m, m_inv, use_m, grey,
                           lut, thresholds, base):  # pragma: no cover - compiled
    """In place on ``out`` (H, W, 3) uint8 within the bbox: object pixels ← encode(M⁻¹ · colour);
    receiver pixels ← encode(M⁻¹ · (ratio ⊙ (M · decode(out)))) (unchanged where the ratio is within
    RATIO_EPS of 1 in every channel); else plane pixels ←
    encode((1 − α) · decode(out) + α · grey)."""
    x = np.empty(3)
    y = np.empty(3)
    for r in range(r0, r1):
        orow = out[r]
        for c in range(c0, c1):
            if mask[r, c]:
                for k in range(3):
                    x[k] = np.float64(colour[r, c, k])
                if use_m:
                    for k in range(3):
                        orow[c, k] = encode8(m_inv[k, 0] * x[0] + m_inv[k, 1] * x[1] + m_inv[k, 2] * x[2],
                                             thresholds, base)
                else:
                    for k in range(3):
                        orow[c, k] = encode8(x[k], thresholds, base)
            elif rmask[r, c]:
                if (abs(np.float64(ratio[r, c, 0]) - 1.0) <= RATIO_EPS and abs(np.float64(ratio[r, c, 1]) - 1.0) <= RATIO_EPS
                        and abs(np.float64(ratio[r, c, 2]) - 1.0) <= RATIO_EPS):
                    continue
                for k in range(3):
                    x[k] = np.float64(lut[orow[c, k]])
                if use_m:
                    for k in range(3):
                        y[k] = (m[k, 0] * x[0] + m[k, 1] * x[1] + m[k, 2] * x[2]) * np.float64(ratio[r, c, k])
                    for k in range(3):
                        orow[c, k] = encode8(m_inv[k, 0] * y[0] + m_inv[k, 1] * y[1] + m_inv[k, 2] * y[2],
                                             thresholds, base)
                else:
                    for k in range(3):
                        orow[c, k] = encode8(x[k] * np.float64(ratio[r, c, k]), thresholds, base)
            else:
                a = np.float64(alpha[r, c])
                if a > 0.0:
                    b = 1.0 - a
                    for k in range(3):
                        orow[c, k] = encode8(b * lut[orow[c, k]] + a * grey[k], thresholds, base)
