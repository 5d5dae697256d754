"""References of the colour stage (:mod:`rgbd_envmap.colour`): the colour-correction fit in closed form,
and the ITU-R BT.601 formulas that NV21 decoding and encoding approximate.

- :func:`ccm_least_squares_reference`: M = ((AᵀA)⁻¹ AᵀB)ᵀ, the least-squares matrix with
  dst ≈ src @ Mᵀ that :func:`rgbd_envmap.colour.estimate_ccm` ("least_squares") fits from its sums;
- :func:`bt601_decode`, :func:`bt601_encode`: limited-range Y'CbCr ↔ R'G'B' (Kr = 0.299,
  Kb = 0.114), real-valued; :func:`rgbd_envmap.colour.decode_nv21` (OpenCV's fixed-point
  ``COLOR_YUV2RGB_NV21``) is within ±1 level of the rounded decode;
- :func:`nv21_planes`: the full-resolution Y, U, V planes of an NV21 buffer;
- :func:`low_confidence_reference`: HDR capture's clip and bracket-dark flags
  (:func:`rgbd_envmap.colour.low_confidence_pixels`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["KR", "KB", "KG", "ccm_least_squares_reference", "bt601_decode", "bt601_encode", "nv21_planes",
           "low_confidence_reference"]

#: ITU-R BT.601 luma weights; limited range: Y' in [16, 235], Cb/Cr in [16, 240] around 128.
KR, KB = 0.299, 0.114
KG = 1.0 - KR - KB


def ccm_least_squares_reference(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """M = ((AᵀA)⁻¹ AᵀB)ᵀ with A = src, B = dst ((N, 3) each), the normal-equation solution of
    min ‖A Mᵀ − B‖², in float64: the colour-correction matrix without the gate."""
    a, b = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    return (np.linalg.inv(a.T @ a) @ (a.T @ b)).T


def bt601_decode(y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Limited-range Y'CbCr → R'G'B' in 0..255, real-valued and clipped. Footroom luma (Y < 16) is
    clamped to 16 as OpenCV does, rather than extrapolated to negative values before the clip."""
    yy = (np.maximum(y, 16.0) - 16.0) * 255.0 / 219.0
    cb = (u - 128.0) * 255.0 / 224.0
    cr = (v - 128.0) * 255.0 / 224.0
    r = yy + 2.0 * (1.0 - KR) * cr
    b = yy + 2.0 * (1.0 - KB) * cb
    g = (yy - KR * r - KB * b) / KG
    return np.clip(np.stack([r, g, b], axis=-1), 0.0, 255.0)


def bt601_encode(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R'G'B' in 0..255 → limited-range (Y', Cb, Cr), real-valued."""
    r, g, b = (rgb[..., i].astype(np.float64) / 255.0 for i in range(3))
    ey = KR * r + KG * g + KB * b
    return 16.0 + 219.0 * ey, 128.0 + 224.0 * (b - ey) / (2 * (1 - KB)), 128.0 + 224.0 * (r - ey) / (2 * (1 - KR))


def nv21_planes(buf: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Full-resolution Y, U, V (float64) from an NV21 buffer: the Y plane, then V, U interleaved at
    half resolution (each chroma sample covers a 2×2 block)."""
    flat = buf.reshape(-1)
    y = flat[: h * w].reshape(h, w).astype(np.float64)
    vu = flat[h * w:].reshape(h // 2, w // 2, 2).astype(np.float64)

    def up(c: np.ndarray) -> np.ndarray:
        return np.repeat(np.repeat(c, 2, axis=0), 2, axis=1)

    return y, up(vu[..., 1]), up(vu[..., 0])


def low_confidence_reference(rgb: np.ndarray, level: float, dark: float | None = None) -> np.ndarray:
    """HDR capture's flags, one pixel at a time: a pixel of (H, W, 3) linear RGB is flagged when any
    channel exceeds ``level`` (clipped) or, with ``dark`` given (a bracket frame), when no channel
    reaches ``dark``. NaN compares false both ways. ``level`` and ``dark`` are compared in the
    array's own precision."""
    h, w, _ = rgb.shape
    level_t, dark_t = rgb.dtype.type(level), rgb.dtype.type(0.0 if dark is None else dark)
    out = np.zeros((h, w), bool)
    for r in range(h):
        for c in range(w):
            px = [rgb[r, c, k] for k in range(3)]
            flag = any(v > level_t for v in px)
            if dark is not None and not any(v >= dark_t for v in px):
                flag = True
            out[r, c] = flag
    return out
