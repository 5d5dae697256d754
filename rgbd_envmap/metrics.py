"""Error metrics for equirectangular environment maps and depth images.

Every equirect metric weights a pixel by the solid angle it covers on the sphere, so that the
over-sampled rows near the poles count no more than the area they represent. The weights come from
:func:`rgbd_envmap.geometry.equirect_solid_angles` (exact, cached per size); this module caches
nothing of its own.

Conventions (docs/reference/conventions.md): maps are (H, W) or channels-last (H, W, C), row 0 at the zenith, any
width (W = 2H in the pipeline; the given shape is used as is). ``valid`` masks are (H, W) bool and
select the pixels that take part; values at invalid pixels are never read (they may be NaN). A NaN or
infinity at a *valid* pixel is an error (:class:`~rgbd_envmap.errors.NonFiniteError`): missing data
must be marked in the mask, not by a magic value, and silently dropping such pixels would hide bugs
upstream.

Degenerate inputs give NaN rather than an exception, so a report over many frames keeps going:
a map with no valid pixels, a reference with no solid angle, a constant channel in a correlation.

References:
    Sun, Lu, Yu (2017). Weighted-to-Spherically-Uniform Quality Evaluation for Omnidirectional Video.
    IEEE Signal Processing Letters 24(9), 1408-1412. (WS-PSNR, eq. 3-5 and the ERP weights.)
    Gutiérrez, David, Rai, Le Callet (2018). Toolbox and dataset for the development of saliency and
    scanpath models for omnidirectional/360° still images. Signal Processing: Image Communication.
    (Sphere-uniform correlation of ODIs, as used by Monroy et al. for their Fig. 9.)
    Monroy, Hudon, Smolic (2018). Dynamic Environment Mapping for Augmented Reality Applications on
    Mobile Devices, §6.2 and Fig. 9 (data loss and correlation after EM translation).
    Debevec (1998). Rendering Synthetic Objects into Real Scenes. SIGGRAPH (a composite is judged
    by the object and by the change it makes to the scene around it: :func:`composite_errors`).
"""

from __future__ import annotations

import math

import numpy as np

from rgbd_envmap.checks import check_array, check_number
from rgbd_envmap.errors import NonFiniteError, RangeError, ShapeError
from rgbd_envmap.geometry import equirect_solid_angles

__all__ = [
    "ws_psnr",
    "sphere_correlation",
    "coverage",
    "coverage_of",
    "data_loss",
    "depth_errors",
    "composite_errors",
]

_NUMERIC = ("float", "int")


# ----------------------------------------------------------------------------------------- checks


def _check_image_pair(a: object, b: object) -> tuple[np.ndarray, np.ndarray]:
    """Return ``a`` and ``b`` as (H, W, C) arrays (a 2-D map gets C = 1), checking that both are
    numeric, 2-D or 3-D, non-empty and of one shape."""
    a = check_array(a, "a", dtype=_NUMERIC)
    b = check_array(b, "b", dtype=_NUMERIC)
    if a.ndim not in (2, 3):
        raise ShapeError(f"a: expected shape (H, W) or (H, W, C), got {a.shape}")
    if b.shape != a.shape:
        raise ShapeError(f"b: expected the shape of a, {a.shape}, got {b.shape}")
    if 0 in a.shape:
        raise ShapeError(f"a: expected a non-empty map, got shape {a.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    return a, b


def _check_mask(mask: object, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """Return ``mask`` as a bool array of ``shape`` (any non-empty 2-D shape when ``None``)."""
    mask = check_array(mask, name, dtype="bool")
    if shape is None:
        if mask.ndim != 2 or 0 in mask.shape:
            raise ShapeError(f"{name}: expected a non-empty (H, W) mask, got shape {mask.shape}")
    elif mask.shape != tuple(shape):
        raise ShapeError(f"{name}: expected shape {tuple(shape)}, got {mask.shape}")
    return mask


def _raise_if_nonfinite(arr: np.ndarray, valid: np.ndarray | None, name: str) -> None:
    """Raise :class:`NonFiniteError` if ``arr`` (H, W, C) holds NaN or inf at a valid pixel."""
    bad = ~np.isfinite(arr)
    if valid is not None:
        bad &= valid[..., None]
    n = int(np.count_nonzero(bad))
    if n:
        where = "at valid pixels" if valid is not None else "(no valid mask given, so every pixel counts)"
        raise NonFiniteError(f"{name}: expected finite values {where}, got {n} NaN or inf")


def _masked_solid_angle(mask: np.ndarray, sa: np.ndarray) -> float:
    """Σ of the solid angles (steradians) of the pixels where ``mask`` is True."""
    return float(np.sum(sa, where=mask))


#: Elements (rows × W × C) of one float64 block in the row-block loops below: 1 MiB per array, so a
#: block pair stays in cache while it is worked on. On a 2000×1000×3 map this runs WS-PSNR ~1.7×
#: and the correlation ~3-5× faster than whole-map float64 temporaries; much smaller blocks pay
#: Python overhead per block (benchmarks/bench_metrics.py times both ways). The sums use
#: ``np.einsum``, not ``@``: OpenBLAS threads its dot products, and on a loaded 2-core machine one
#: such call was measured at ~8 ms instead of ~30 µs.
_BLOCK_ELEMENTS = 1 << 17


def _row_blocks(a: np.ndarray, b: np.ndarray, valid: np.ndarray | None):
    """Yield ``(weights, A, B)`` for consecutive blocks of rows of (H, W, C) maps ``a`` and ``b``.

    ``weights`` is the (R, W) float64 pixel solid angle, zero at invalid pixels; ``A`` and ``B`` are
    (C, R, W) C-contiguous float64 copies (channels first: each channel is one contiguous plane),
    zeroed at invalid pixels when those hold NaN or inf. The copies live in buffers reused from
    block to block: consume each block before taking the next.

    Raises:
        NonFiniteError: NaN or inf in ``a`` or ``b`` at a valid pixel.
    """
    h, w, c = a.shape
    sa = equirect_solid_angles(h, w)
    rows = max(1, _BLOCK_ELEMENTS // (w * c))
    buf_a = np.empty(c * rows * w)
    buf_b = np.empty(c * rows * w)
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        n = c * (r1 - r0) * w
        blk_a = buf_a[:n].reshape(c, r1 - r0, w)
        blk_b = buf_b[:n].reshape(c, r1 - r0, w)
        np.copyto(blk_a, a[r0:r1].transpose(2, 0, 1))
        np.copyto(blk_b, b[r0:r1].transpose(2, 0, 1))
        v = None if valid is None else valid[r0:r1]
        for blk, full, name in ((blk_a, a, "a"), (blk_b, b, "b")):
            if not np.isfinite(blk).all():
                if v is not None:
                    np.copyto(blk, 0.0, where=~v)  # values at invalid pixels are never read
                if v is None or not np.isfinite(blk).all():
                    _raise_if_nonfinite(full, valid, name)
        weights = sa[r0:r1] if v is None else sa[r0:r1] * v
        yield weights, blk_a, blk_b


# ---------------------------------------------------------------------------------- image metrics


def ws_psnr(a: np.ndarray, b: np.ndarray, valid: np.ndarray | None = None, peak: float = 1.0) -> float:
    """Weighted-to-spherically-uniform PSNR (WS-PSNR) between two equirect maps, in dB.

    Each pixel is weighted by its solid angle ω (steradians):

        WMSE = Σ_valid Σ_c ω (a − b)² / (C · Σ_valid ω),    WS-PSNR = 10 log10(peak² / WMSE).

    Channels are pooled into one WMSE (one figure per RGB map, like the usual colour PSNR); pass one
    channel at a time for per-channel figures.

    Sun et al. weight an ERP pixel by cos(latitude) at its centre. This function uses the exact
    solid angle (2π/W)(cos θ_top − cos θ_bottom) instead, which keeps the weights in steradians like
    every other metric here. For an equirect grid the two are *exactly* proportional,
    cos θ_top − cos θ_bottom = 2 sin(π / 2H) · sin θ_centre, and WMSE is a ratio of weighted sums, so
    the dB figure equals the paper's up to float64 rounding (tested).

    Args:
        a, b: (H, W) or (H, W, C) float or int maps of one shape, e.g. linear radiance. Computed in
            float64 whatever the input dtype (uint8 does not wrap around).
        valid: (H, W) bool, the pixels that take part (e.g. ``em.valid & truth.valid``); all when
            ``None``. Values at invalid pixels are ignored and may be NaN.
        peak: the signal peak, in (0, 1e150]: 1.0 for maps in [0, 1], 255 for 8-bit. Radiance is
            unbounded above, so for HDR maps pick a peak and report it beside the figure.

    Returns:
        WS-PSNR in dB as a float: ``+inf`` when the maps agree at every valid pixel, ``NaN`` when no
        pixel is valid, ``-inf`` if squared differences overflow float64 (|a − b| > ~1e154).

    Raises:
        ShapeError: ``a`` and ``b`` differ in shape, are not 2-D / 3-D, or ``valid`` is not (H, W).
        DTypeError: non-numeric maps, or ``valid`` not bool.
        NonFiniteError: NaN or inf in ``a`` or ``b`` at a valid pixel.
        RangeError: ``peak`` not finite and positive.

    Example:
        >>> a = np.zeros((4, 8, 3), np.float32)
        >>> round(ws_psnr(a, a + 0.1), 6)
        20.0
    """
    a, b = _check_image_pair(a, b)
    h, w, c = a.shape
    if valid is not None:
        valid = _check_mask(valid, "valid", (h, w))
    peak = check_number(peak, "peak", low=0.0, low_open=True, high=1e150)  # peak² stays finite

    num = den = 0.0
    with np.errstate(over="ignore", invalid="ignore"):
        for weights, blk_a, blk_b in _row_blocks(a, b, valid):
            blk_a -= blk_b
            blk_a *= blk_a
            num += float(np.einsum("rw,rw->", weights, blk_a.sum(axis=0)))  # Σ ω Σ_c (a − b)²
            den += float(weights.sum())
    if den == 0.0:
        return math.nan
    if num == 0.0:
        return math.inf
    if not math.isfinite(num):
        return -math.inf  # finite inputs (checked per block) whose squares overflow
    return 10.0 * math.log10(peak * peak * c * den / num)


def sphere_correlation(
    a: np.ndarray, b: np.ndarray, valid: np.ndarray | None = None, *, per_channel: bool = False
) -> float | np.ndarray:
    """Solid-angle-weighted Pearson correlation between two equirect maps, averaged over channels.

    Per channel, with pixel solid angles ω as weights over the valid pixels:

        μ_a = Σ ω a / Σ ω,   r = Σ ω (a − μ_a)(b − μ_b) / sqrt(Σ ω (a − μ_a)² · Σ ω (b − μ_b)²).

    This is the continuous form of correlating values sampled uniformly on the sphere (Gutiérrez et
    al.'s ODI toolbox), the protocol of Monroy et al.'s Fig. 9, which reports the mean over channels
    of the correlation between a translated EM and the ground-truth EM. Computed in float64 with
    two passes (means, then centred sums), which stays accurate when the mean dwarfs the spread.

    A channel that is constant over the valid pixels of ``a`` or of ``b`` (all values exactly equal,
    zero variance) has no correlation: its r is NaN, and the mean is taken over the other channels.
    The result is NaN when every channel is constant, when fewer than two pixels are valid, or
    when no pixel is valid.

    Args:
        a, b: (H, W) or (H, W, C) float or int maps of one shape.
        valid: (H, W) bool, the pixels that take part; all when ``None``. Values at invalid pixels
            are ignored and may be NaN.
        per_channel: return the (C,) float64 array of per-channel r (NaN for constant channels)
            instead of their mean.

    Returns:
        r in [−1, 1] as a float (mean over the non-constant channels), or (C,) float64 when
        ``per_channel``.

    Raises:
        ShapeError, DTypeError, NonFiniteError: as :func:`ws_psnr`.

    Example:
        >>> a = np.random.default_rng(0).random((4, 8, 3))
        >>> round(sphere_correlation(a, 2 * a + 1), 12), round(sphere_correlation(a, -a), 12)
        (1.0, -1.0)
    """
    a, b = _check_image_pair(a, b)
    h, w, c = a.shape
    if valid is not None:
        valid = _check_mask(valid, "valid", (h, w))
    n_valid = h * w if valid is None else int(np.count_nonzero(valid))
    r = np.full(c, np.nan)
    if n_valid == 1:  # no correlation, but a NaN there is still an error
        _raise_if_nonfinite(a, valid, "a")
        _raise_if_nonfinite(b, valid, "b")
    if n_valid >= 2:
        total, sum_a, sum_b = 0.0, np.zeros(c), np.zeros(c)
        with np.errstate(over="ignore", invalid="ignore"):
            for weights, blk_a, blk_b in _row_blocks(a, b, valid):
                total += float(weights.sum())
                sum_a += np.einsum("crw,rw->c", blk_a, weights)
                sum_b += np.einsum("crw,rw->c", blk_b, weights)
            mu_a, mu_b = sum_a / total, sum_b / total
            cov, var_a, var_b = np.zeros(c), np.zeros(c), np.zeros(c)
            for weights, blk_a, blk_b in _row_blocks(a, b, valid):
                sqrt_w = np.sqrt(weights)
                blk_a -= mu_a[:, None, None]
                blk_b -= mu_b[:, None, None]
                blk_a *= sqrt_w
                blk_b *= sqrt_w
                cov += np.einsum("crw,crw->c", blk_a, blk_b)
                var_a += np.einsum("crw,crw->c", blk_a, blk_a)
                var_b += np.einsum("crw,crw->c", blk_b, blk_b)
        # A constant channel's centred sums come out tiny but not zero (its computed mean is off by
        # rounding, at most ~N ε |μ|), so channels that small get an exact test.
        eps = np.finfo(np.float64).eps
        for k in range(c):
            small_a = var_a[k] <= total * (16 * n_valid * eps * abs(mu_a[k])) ** 2
            small_b = var_b[k] <= total * (16 * n_valid * eps * abs(mu_b[k])) ** 2
            if (small_a and _is_constant(a[..., k], valid)) or (small_b and _is_constant(b[..., k], valid)):
                continue
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                r[k] = np.clip(cov[k] / math.sqrt(var_a[k] * var_b[k]), -1.0, 1.0)
    if per_channel:
        return r
    finite = r[~np.isnan(r)]
    return float(finite.mean()) if finite.size else math.nan


def _is_constant(channel: np.ndarray, valid: np.ndarray | None) -> bool:
    """True when every valid value of the (H, W) ``channel`` is the same."""
    values = channel.reshape(-1) if valid is None else channel[valid]
    return bool(np.all(values == values[0]))


# -------------------------------------------------------------------------------- coverage metrics


def coverage(valid: np.ndarray) -> float:
    """Fraction of the sphere's solid angle covered by the valid pixels of an equirect map.

    Args:
        valid: (H, W) bool.

    Returns:
        Σ_valid ω / Σ ω in [0, 1] (Σ ω = 4π): 1 for an all-valid map, 0.5 for the northern half of a
        map with even H (up to float64 rounding).

    Raises:
        ShapeError: ``valid`` not a non-empty 2-D array.
        DTypeError: ``valid`` not bool.
    """
    valid = _check_mask(valid, "valid")
    sa = equirect_solid_angles(*valid.shape)
    return _masked_solid_angle(valid, sa) / float(sa.sum())


def coverage_of(valid: np.ndarray, reference_valid: np.ndarray) -> float:
    """Fraction of the reference's solid angle that ``valid`` covers, e.g. how much of the
    ground-truth EM's data a captured EM has ("coverage ≥ 95 % of the GT EM's solid angle").

    Args:
        valid: (H, W) bool, the map under test.
        reference_valid: (H, W) bool, the reference map's valid pixels.

    Returns:
        Σ_{valid ∧ reference} ω / Σ_reference ω in [0, 1]; pixels valid only in ``valid`` do not
        count. NaN when the reference has no valid pixel.

    Raises:
        ShapeError: the masks differ in shape or are not non-empty 2-D.
        DTypeError: either mask not bool.
    """
    reference_valid = _check_mask(reference_valid, "reference_valid")
    valid = _check_mask(valid, "valid", reference_valid.shape)
    sa = equirect_solid_angles(*valid.shape)
    ref = _masked_solid_angle(reference_valid, sa)
    if ref == 0.0:
        return math.nan
    return _masked_solid_angle(valid & reference_valid, sa) / ref


def data_loss(before_valid: np.ndarray, after_valid: np.ndarray) -> float:
    """Solid-angle fraction of an equirect map's data lost by an operation such as EM translation
    (Monroy et al. §6.2, Fig. 9): pixels valid before and invalid after, relative to the solid angle
    valid before. Both masks are on the same pixel grid (pixel = direction from the map's origin).
    Pixels that gain data are not counted, so this is ``1 − coverage_of(after, before)``.

    Args:
        before_valid: (H, W) bool, valid pixels before the operation.
        after_valid: (H, W) bool, valid pixels after it.

    Returns:
        Σ_{before ∧ ¬after} ω / Σ_before ω in [0, 1]; NaN when nothing was valid before.

    Raises:
        ShapeError: the masks differ in shape or are not non-empty 2-D.
        DTypeError: either mask not bool.
    """
    before_valid = _check_mask(before_valid, "before_valid")
    after_valid = _check_mask(after_valid, "after_valid", before_valid.shape)
    sa = equirect_solid_angles(*before_valid.shape)
    before = _masked_solid_angle(before_valid, sa)
    if before == 0.0:
        return math.nan
    return _masked_solid_angle(before_valid & ~after_valid, sa) / before


# ----------------------------------------------------------------------------------- depth metrics


def depth_errors(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict:
    """Summary of depth errors ``estimate − truth`` over the masked pixels, in metres.

    Generic: any shape, any depth convention (z-depth for frames, Euclidean distance for EMs) as
    long as both arrays use the same one. Pixels count equally (no solid-angle weighting).

    Args:
        estimate: (...) float or int depths, metres.
        truth: (...) depths of the same shape, metres.
        mask: (...) bool of the same shape, the pixels to evaluate (e.g. ``filled & truth_valid``).
            Values outside the mask are ignored and may be NaN.

    Returns:
        dict with float ``mae`` (mean |e|), ``rmse``, ``median_abs``, ``p95_abs`` (95th percentile of
        |e|, linear interpolation as ``np.percentile``), ``bias`` (mean signed e) and int ``n`` (the
        number of masked pixels). With ``n == 0`` every float is NaN.

    Raises:
        ShapeError: shapes differ.
        DTypeError: non-numeric depths or ``mask`` not bool.
        NonFiniteError: NaN or inf in ``estimate`` or ``truth`` inside the mask.
    """
    estimate = check_array(estimate, "estimate", dtype=_NUMERIC)
    truth = check_array(truth, "truth", dtype=_NUMERIC)
    if truth.shape != estimate.shape:
        raise ShapeError(f"truth: expected the shape of estimate, {estimate.shape}, got {truth.shape}")
    mask = check_array(mask, "mask", dtype="bool")
    if mask.shape != estimate.shape:
        raise ShapeError(f"mask: expected the shape of estimate, {estimate.shape}, got {mask.shape}")
    est, tru = estimate[mask].astype(np.float64), truth[mask].astype(np.float64)
    for arr, name in ((est, "estimate"), (tru, "truth")):
        if not np.isfinite(arr).all():
            n_bad = int(np.count_nonzero(~np.isfinite(arr)))
            raise NonFiniteError(f"{name}: expected finite values inside mask, got {n_bad} NaN or inf")
    n = int(est.size)
    if n == 0:
        return {"mae": math.nan, "rmse": math.nan, "median_abs": math.nan, "p95_abs": math.nan,
                "bias": math.nan, "n": 0}
    e = est - tru
    ae = np.abs(e)
    return {
        "mae": float(ae.mean()),
        "rmse": float(np.sqrt(np.mean(e * e))),
        "median_abs": float(np.median(ae)),
        "p95_abs": float(np.percentile(ae, 95)),
        "bias": float(e.mean()),
        "n": n,
    }


#: luminance weights (Rec. 709 primaries, linear), for the shadow region of :func:`composite_errors`.
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _box_mean(a: np.ndarray, weight: np.ndarray, k: int) -> np.ndarray:
    """Mean of ``a`` over the k×k window around each pixel, counting only pixels of weight 1."""
    import cv2

    num = cv2.boxFilter(np.where(weight, a, 0.0), -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    den = cv2.boxFilter(weight.astype(np.float64), -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return num / np.maximum(den, 1.0)


def composite_errors(ours: np.ndarray, with_object: np.ndarray, without_object: np.ndarray,
                     object_mask: np.ndarray, valid: np.ndarray, *, shadow_threshold: float = 0.02,
                     window_px: int = 7) -> dict:
    """Errors of a composited frame against a reference rendered with and without the virtual object.

    All three images are linear radiance of the same view (the composite with the camera's gains
    undone). Three regions:

    - **object**: ``object_mask & valid``, the pixels that see the virtual object;
    - **shadow**: valid pixels off the object where the object changes the scene, i.e. where the
      reference's luminance with and without the object differ by more than ``shadow_threshold`` of
      the luminance without it (its shadow, and the light it bounces). Both luminances are first
      averaged over a ``window_px`` square of valid off-object pixels, so that the path tracer's
      noise does not make a speckle of isolated "changed" pixels;
    - **all**: the two together.

    Each error is the relative RMSE over the region's pixels and channels,
    ``sqrt(Σ (ours − with_object)² / Σ with_object²)``.

    Args:
        ours: (H, W, 3) float, the composite. with_object, without_object: (H, W, 3) float references.
        object_mask: (H, W) bool. valid: (H, W) bool, the pixels that can be compared (values
            elsewhere are not read and may be NaN).
        shadow_threshold: > 0, relative. window_px: odd ≥ 1.

    Returns:
        dict with float ``object_rel_rmse``, ``shadow_rel_rmse``, ``rel_rmse`` (NaN for an empty
        region, or one whose reference is black) and int ``object_pixels``, ``shadow_pixels``; ``shadow_mask`` (H, W) bool.

    Raises:
        ShapeError, DTypeError, NonFiniteError (a NaN or inf at a valid pixel), RangeError.
    """
    ours = check_array(ours, "ours", shape=("H", "W", 3), dtype=_NUMERIC)
    h, w = ours.shape[:2]
    if h == 0 or w == 0:
        raise ShapeError(f"ours: expected a non-empty image, got shape {ours.shape}")
    with_object = check_array(with_object, "with_object", shape=(h, w, 3), dtype=_NUMERIC)
    without_object = check_array(without_object, "without_object", shape=(h, w, 3), dtype=_NUMERIC)
    object_mask = _check_mask(object_mask, "object_mask", (h, w))
    valid = _check_mask(valid, "valid", (h, w))
    threshold = check_number(shadow_threshold, "shadow_threshold", low=0.0, low_open=True)
    k = int(check_number(window_px, "window_px", low=1, high=255, integer=True))
    if k % 2 == 0:
        raise RangeError(f"window_px: expected an odd number, got {k}")
    for arr, name in ((ours, "ours"), (with_object, "with_object"), (without_object, "without_object")):
        _raise_if_nonfinite(arr, valid, name)
    a = np.where(valid[..., None], ours, 0.0).astype(np.float64)
    ref = np.where(valid[..., None], with_object, 0.0).astype(np.float64)
    bg = np.where(valid[..., None], without_object, 0.0).astype(np.float64)
    off = valid & ~object_mask
    change = _box_mean(np.abs((ref - bg) @ _LUMA), off, k)
    level = _box_mean(bg @ _LUMA, off, k)
    shadow = off & (change > threshold * np.maximum(level, 1e-12))
    obj = object_mask & valid

    def rel_rmse(mask: np.ndarray) -> float:
        if not mask.any():
            return math.nan
        den = float(np.sum(ref[mask] ** 2))
        return math.sqrt(float(np.sum((a[mask] - ref[mask]) ** 2)) / den) if den > 0 else math.nan

    return {"object_rel_rmse": rel_rmse(obj), "shadow_rel_rmse": rel_rmse(shadow), "rel_rmse": rel_rmse(obj | shadow),
            "object_pixels": int(obj.sum()), "shadow_pixels": int(shadow.sum()), "shadow_mask": shadow}
