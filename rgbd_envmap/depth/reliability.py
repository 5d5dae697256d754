"""Reliability marking of an RGB-D frame (paper 003 §5.2): which pixels may be paired with the EM.

A pixel is **reliable** when all of these hold:

1. it is ``known`` and its depth is finite and > 0;
2. it is neither under- nor over-exposed: *not* (R, G and B all < ``dark``) and *not* (R, G and B all
   > ``bright``) (paper: 0.05 and 0.95 on linear values in [0, 1]). The comparisons are strict, so a
   pixel with every channel exactly 0.05 (or exactly 0.95) is *not* rejected by this rule. Values
   outside [0, 1] are allowed (radiance is unbounded above); they simply count as dark or bright. A
   pixel with any non-finite channel is unreliable;
3. it passes a depth-discontinuity test on its 3×3 neighbourhood (depth only, as in the paper).

Marking happens before hole filling, so only measured depth takes part. The exposure rule does not
remove a pixel's depth from its neighbours' tests: exposure says nothing about depth.

Discontinuity tests (``method``)
--------------------------------
``"monroy2018"`` -- the authors' implementation::

    S = Σ_{i ∈ known 8-neighbours} (d_i − d)² / d,    reject when S > 14.07 (χ² 0.95-quantile, 7 dof)

with ``d`` the z-depth in **metres**. ``S`` is a Pearson-style statistic that treats the depth as a
count (variance = mean); it has the units of depth, so its value, and the meaning of the threshold,
change with the unit (×1000 in millimetres). On a noisy wall with 1 % range noise E[S] ≈ 16 σ²/z =
1.6·10⁻³ z (in metres), four orders of magnitude under 14.07, and a step of height h with three
neighbours across it gives S ≈ 3 h² / z, which exceeds 14.07 only for h > 2.2 m · √(z / 1 m). In
metres the test therefore keeps every wall *and* every edge (measured: 0 % of walls and 0 % of
1–30 cm step edges rejected at 0.5–4 m); fed millimetres it rejects 10 cm steps at 1 m but also
27 % of a 70° wall at 4 m. docs/design/reliability.md has the measurements.

``"noise_model"`` (default) -- a χ² test derived from the ToF sensor's noise model. The range noise
is Gaussian with σ = ``noise_abs_m`` + ``noise_rel`` · range; along a pixel ray z-depth is range
times a constant, so σ_z = ``noise_abs_m`` + ``noise_rel`` · z (the relative part exactly, the absolute
part up to the ray's cos factor ≤ 1, i.e. conservatively). A plane Z = a X + b Y + c seen by a pinhole
camera has **inverse depth affine in the image coordinates**: 1/z = (1 − a x − b y) / c with
x = X/Z, y = Y/Z. So on the n ≤ 9 known pixels of the 3×3 window (centre included), with pixel offsets
(du, dv) ∈ {−1, 0, 1}²,

    w_i = 1 / z_i,    σ_w,i = σ_z(z_i) / z_i²    (first-order propagation of σ_z to 1/z)
    fit w ≈ β₀ + β₁ du + β₂ dv by weighted least squares (weights 1/σ_w,i²)
    T = Σ_i (w_i − ŵ_i)² / σ_w,i²  ~  χ²(n − 3)   when the window is one plane

and the pixel is rejected when T exceeds the χ² (1 − ``p_value``)-quantile for n − 3 degrees of
freedom. ``T`` is dimensionless and scale-free: with ``noise_abs_m`` = 0 it depends only on relative
depth, so a wall keeps the same false-rejection rate (≈ ``p_value``) at every distance and
incidence angle, and a step is detected according to its height relative to the noise, h / σ_z.
The plane model's own error is negligible: on noise-free planes seen through the distorted default
ToF camera, T stays below 2·10⁻⁵ (a wall's mean is n − 3 ≈ 6) up to 80° incidence, whereas fitting
z instead of 1/z leaves curvature residuals up to T ≈ 0.35 at 70° and 3.9 at 80°
(docs/design/reliability.md). All weighted sums are separable 3×3 filters, so the test costs one pass.

Neighbours
----------
Four known pixels in a 3×3 grid are never collinear, so the plane fit is determined once a pixel
has ≥ 3 known neighbours; with fewer, ``noise_model`` cannot test the pixel and marks it unreliable.
Beyond that, ``min_neighbours`` asks for that many known 8-neighbours *among those inside the image*
(the requirement is min(``min_neighbours``, in-image neighbours), so image borders and corners are
not penalised). A pixel short of it is unreliable. The default for ``noise_model`` is 8: every
in-image neighbour must be known. An unknown neighbour means the sensor dropped that pixel (a mixed
pixel at a depth edge, a shiny / dark / emissive surface, grazing incidence, out of range), which
can hide the very discontinuity the test looks for: in the simulator every true depth jump > 5 %
comes with such a dropout, and this rule finds all of them (docs/design/reliability.md). Sensors with
speckled, isolated dropouts may prefer a lower value. ``monroy2018`` defaults to 0, as the authors
test every known pixel.

What a 3×3 test cannot do: against an unconstrained plane, a step of height h across a column
boundary leaves only T = (h / σ_z)² / 2 of non-planar signal (the plane's slope absorbs the rest),
so even a noise-free 10 cm step at 3 m (h/σ = 3.3, T = 5.6) sits inside the 95 % range of a wall.
No 8-neighbour test that keeps slanted walls can reject it reliably (Neyman–Pearson bound 76 %; this
test 37 %); see docs/design/reliability.md.

Non-finite input
----------------
Never raises and never yields NaN: a known pixel with NaN / inf / ≤ 0 depth is treated as unknown
(unreliable, and left out of its neighbours' tests); a pixel with any NaN / inf colour channel is
unreliable; a window whose arithmetic overflows (absurd depths) is rejected. The depth values of
unknown pixels are never used.

The per-pixel work runs in numba kernels (:mod:`rgbd_envmap._kernels.reliability`; single thread, no
image-sized scratch); benchmarks/bench_reliability.py times them.

Example:
    >>> import numpy as np
    >>> z = np.full((5, 6), 2.0); z[:, 3:] = 2.5                      # a 50 cm step at 2 m
    >>> rgb = np.full((5, 6, 3), 0.5); known = np.ones((5, 6), bool)
    >>> mark_reliable(rgb, z, known)[2].tolist()
    [True, True, False, False, True, True]

References:
    Monroy, Hudon, Smolic (2018), *Dynamic Environment Mapping for Augmented Reality Applications on
    Mobile Devices*, §5.2 (exposure rule and χ² test on the 8-connected pixels).
    Mitsunaga, Nayar (1999), *Radiometric Self Calibration*, CVPR (χ² test for flat regions).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from types import MappingProxyType

import numpy as np

from rgbd_envmap._kernels import reliability as kernels
from rgbd_envmap.checks import check_array, check_method
from rgbd_envmap.errors import DTypeError, RangeError, ShapeError

__all__ = [
    "RELIABILITY_METHODS",
    "MONROY2018_THRESHOLD",
    "MIN_NEIGHBOURS_DEFAULT",
    "DiscontinuityTest",
    "exposure_ok",
    "discontinuity_test",
    "discontinuity_passed",
    "mark_reliable",
]

#: Names accepted by ``method``: the default derived from the sensor's noise model, and the authors'.
RELIABILITY_METHODS = ("noise_model", "monroy2018")

#: The authors' threshold on Σ (d_i − d)² / d: the χ² 0.95-quantile at 7 degrees of freedom (14.067).
MONROY2018_THRESHOLD = 14.07

#: Default ``min_neighbours`` per method (read-only): the authors test every known pixel (a pixel
#: with no known neighbour has S = 0 and passes); the noise-model test asks for every in-image
#: neighbour to be known (docs/design/reliability.md measures the choice on the simulator).
MIN_NEIGHBOURS_DEFAULT = MappingProxyType({"noise_model": 8, "monroy2018": 0})


@dataclass(frozen=True)
class DiscontinuityTest:
    """Per-pixel outcome of a depth-discontinuity test (all arrays (H, W)).

    Attributes:
        statistic: float64 test statistic (dimensionless χ² for ``noise_model``; metres for
            ``monroy2018``); 0 where not ``testable``, +inf where the arithmetic overflowed.
        threshold: float64 rejection threshold for the pixel's degrees of freedom (0 where not testable).
        n_neighbours: int8 number of known 8-neighbours inside the image (0 at unknown pixels).
        testable: bool, the pixel is known with finite depth > 0, has ≥ min(``min_neighbours``, its
            in-image neighbours) known neighbours, and (``noise_model``) ≥ 3 for the plane fit.
        passed: bool, ``testable`` and ``statistic`` ≤ ``threshold``.
    """

    statistic: np.ndarray
    threshold: np.ndarray
    n_neighbours: np.ndarray
    testable: np.ndarray
    passed: np.ndarray


def _float32_thresholds(dark: float, bright: float) -> tuple[np.float32, np.float32]:
    """float32 (d, b) with x < d ⇔ x < dark and x > b ⇔ x > bright for every float32 x (compared
    exactly, as float64): d is the smallest float32 ≥ dark, b the largest ≤ bright."""
    with np.errstate(over="ignore"):
        d, b = np.float32(dark), np.float32(bright)
    if float(d) < dark:
        d = np.nextafter(d, np.float32(np.inf))
    if float(b) > bright:
        b = np.nextafter(b, np.float32(-np.inf))
    return d, b


def _apply_exposure(rgb: np.ndarray, dark: float, bright: float, passed: np.ndarray) -> None:
    """passed &= exposure_ok(rgb) (C-contiguous float32 or float64 rgb)."""
    if rgb.dtype == np.float32:
        kernels.exposure_and_f32(rgb, *_float32_thresholds(dark, bright), passed)
    else:
        kernels.exposure_and_f64(rgb, dark, bright, passed)


# --------------------------------------------------------------------------------------------------
# Public functions
# --------------------------------------------------------------------------------------------------


@lru_cache(maxsize=64)
def _chi2_thresholds(p_value: float) -> np.ndarray:
    """Rejection threshold of the plane-fit χ² by number of known neighbours 0 … 8: the χ²
    (1 − p)-quantile at n − 3 = neighbours − 2 degrees of freedom; −1 (untestable) below 3."""
    from scipy.stats import chi2  # noqa: PLC0415 - scipy.stats is slow to import; only needed here

    out = np.full(9, -1.0)
    out[3:] = chi2.isf(p_value, np.arange(1, 7))
    out.setflags(write=False)
    return out


def _monroy2018_thresholds(value: float) -> np.ndarray:
    """The authors' threshold, the same for every number of known neighbours 0 … 8."""
    return np.full(9, float(value))


def _check_inputs(depth_m, known, rgb=None):
    depth_m = check_array(depth_m, "depth_m", shape=("H", "W"), dtype="float")
    known = check_array(known, "known", dtype="bool")
    if known.shape != depth_m.shape:
        raise ShapeError(f"known: expected shape {depth_m.shape} (that of depth_m), got {known.shape}")
    if rgb is not None:
        rgb = check_array(rgb, "rgb", dtype="float")
        if rgb.shape != depth_m.shape + (3,):
            raise ShapeError(f"rgb: expected shape {depth_m.shape + (3,)} (depth_m's (H, W) + (3,)), got {rgb.shape}")
    return depth_m, known, rgb


def _check_fraction(value: float, name: str, low: float, high: float, *, open_low: bool = False) -> float:
    value = float(value)
    ok = (low < value if open_low else low <= value) and value <= high
    if not ok:
        interval = f"({low}, {high}]" if open_low else f"[{low}, {high}]"
        raise RangeError(f"{name}: expected a value in {interval}, got {value}")
    return value


def exposure_ok(rgb: np.ndarray, *, dark: float = 0.05, bright: float = 0.95) -> np.ndarray:
    """The paper's exposure rule: (..., 3) linear RGB float → (...) bool, False where all three
    channels are < ``dark`` (under-exposed) or all three are > ``bright`` (over-exposed), or where any
    channel is NaN / inf. The comparisons are strict: a channel equal to ``dark`` is not dark.

    Example:
        >>> exposure_ok(np.array([[0.04, 0.04, 0.04], [0.05, 0.04, 0.04], [0.96, 0.96, 0.96]])).tolist()
        [False, True, False]
    """
    rgb = check_array(rgb, "rgb", shape=("*", 3), dtype="float")
    dark, bright = _check_exposure_thresholds(dark, bright)
    flat = _kernel_float(rgb.reshape(-1, 1, 3))
    out = np.ones(flat.shape[:2], bool)
    if flat.shape[0]:
        _apply_exposure(flat, dark, bright, out)
    return out.reshape(rgb.shape[:-1])


def _kernel_float(a: np.ndarray) -> np.ndarray:
    """C-contiguous float32 or float64 (the dtypes the kernels are compiled for)."""
    return np.ascontiguousarray(a, dtype=a.dtype if a.dtype in (np.float32, np.float64) else np.float64)


def _check_exposure_thresholds(dark, bright) -> tuple[float, float]:
    dark, bright = float(dark), float(bright)
    if not (np.isfinite(dark) and np.isfinite(bright)):
        raise RangeError(f"dark, bright: expected finite thresholds, got {dark}, {bright}")
    return dark, bright


def _run(depth_m, known, rgb, method, noise_rel, noise_abs_m, p_value, min_neighbours, monroy2018_threshold,
         dark=0.0, bright=1.0, full=True):
    """Validate the test parameters and run the kernel of ``method``; ``rgb`` None skips exposure."""
    method = check_method(method, RELIABILITY_METHODS)
    if min_neighbours is None:
        min_neighbours = MIN_NEIGHBOURS_DEFAULT[method]
    if isinstance(min_neighbours, bool) or not isinstance(min_neighbours, (int, np.integer)):
        raise DTypeError(f"min_neighbours: expected an integer in [0, 8], got {min_neighbours!r}")
    lowest = 3 if method == "noise_model" else 0
    if not lowest <= min_neighbours <= 8:
        raise RangeError(f"min_neighbours: expected an integer in [{lowest}, 8] for method {method!r}, got {min_neighbours}")
    noise_rel, noise_abs_m = float(noise_rel), float(noise_abs_m)
    for name, value in (("noise_rel", noise_rel), ("noise_abs_m", noise_abs_m)):
        if not 0.0 <= value < np.inf:
            raise RangeError(f"{name}: expected a finite value ≥ 0, got {value}")
    if method == "noise_model" and noise_rel == 0.0 and noise_abs_m == 0.0:
        raise RangeError("noise_rel, noise_abs_m: the noise model needs σ > 0, got both 0")
    p_value = _check_fraction(p_value, "p_value", 0.0, 1.0, open_low=True)
    monroy2018_threshold = float(monroy2018_threshold)
    if not 0.0 <= monroy2018_threshold < np.inf:
        raise RangeError(f"monroy2018_threshold: expected a finite value ≥ 0, got {monroy2018_threshold}")

    shape = depth_m.shape
    out_shape = shape if full else (1, 1)
    stat = np.zeros(out_shape)
    threshold = np.zeros(out_shape)
    n_nb = np.zeros(out_shape, np.int8)
    passed = np.zeros(shape, bool)
    testable = np.zeros(shape, bool)
    if depth_m.size == 0:
        return stat, threshold, n_nb, passed, testable
    depth = _kernel_float(depth_m)
    known = np.ascontiguousarray(known)
    if method == "monroy2018":
        kernels.monroy2018_kernel(
            depth, known, _monroy2018_thresholds(monroy2018_threshold), min_neighbours, full, stat, n_nb, threshold,
            passed, testable,
        )
    else:
        kernels.noise_model_kernel(
            depth, known, noise_rel, noise_abs_m, _chi2_thresholds(p_value), min_neighbours, full, stat, n_nb,
            threshold, passed, testable,
        )
    if rgb is not None:
        _apply_exposure(_kernel_float(rgb), dark, bright, passed)
    return stat, threshold, n_nb, passed, testable


def discontinuity_test(
    depth_m: np.ndarray,
    known: np.ndarray,
    method: str = "noise_model",
    *,
    noise_rel: float = 0.01,
    noise_abs_m: float = 0.0,
    p_value: float = 0.05,
    min_neighbours: int | None = None,
    monroy2018_threshold: float = MONROY2018_THRESHOLD,
) -> DiscontinuityTest:
    """Run the depth-discontinuity test of ``method`` on every pixel (depth only; see the module
    docstring). :func:`mark_reliable` is this test's ``passed`` and the exposure rule.

    Args:
        depth_m: (H, W) float z-depth in metres; read only where ``known``.
        known: (H, W) bool. Known pixels with non-finite or ≤ 0 depth are treated as unknown.
        method: one of :data:`RELIABILITY_METHODS`.
        noise_rel, noise_abs_m: the sensor model σ_z = noise_abs_m + noise_rel · z (``noise_model``).
        p_value: false-rejection probability of the χ² test on a plane (``noise_model``).
        min_neighbours: known 8-neighbours a pixel needs to be testable, capped by its in-image
            neighbours (borders: 5, corners: 3). 0 … 8; ≥ 3 for ``noise_model``, whose plane fit
            needs n − 3 ≥ 1 degrees of freedom. None: :data:`MIN_NEIGHBOURS_DEFAULT` (8 for
            ``noise_model`` = every in-image neighbour known; 0 for ``monroy2018``).
        monroy2018_threshold: the threshold of ``monroy2018`` (paper: 14.07).

    Returns:
        A :class:`DiscontinuityTest` of (H, W) arrays.

    Example:
        >>> z = np.full((4, 4), 1.0); z[:, 2:] = 1.2                     # a 20 cm step at 1 m
        >>> t = discontinuity_test(z, np.ones((4, 4), bool))
        >>> bool(t.testable.all()), bool(t.passed[:, 1:3].any()), round(float(t.threshold[1, 1]), 2)
        (True, False, 12.59)
    """
    depth_m, known, _ = _check_inputs(depth_m, known)
    stat, threshold, n_nb, passed, testable = _run(
        depth_m, known, None, method, noise_rel, noise_abs_m, p_value, min_neighbours, monroy2018_threshold,
    )
    return DiscontinuityTest(stat, threshold, n_nb, testable, passed)


def discontinuity_passed(
    depth_m: np.ndarray,
    known: np.ndarray,
    method: str = "noise_model",
    *,
    noise_rel: float = 0.01,
    noise_abs_m: float = 0.0,
    p_value: float = 0.05,
    min_neighbours: int | None = None,
    monroy2018_threshold: float = MONROY2018_THRESHOLD,
) -> np.ndarray:
    """``discontinuity_test(...).passed`` (same arguments and errors) without the per-pixel
    statistic, threshold and neighbour count, which cost time to write: for callers that need the mask
    only (the capture's edge margin, every depth frame)."""
    depth_m, known, _ = _check_inputs(depth_m, known)
    return _run(
        depth_m, known, None, method, noise_rel, noise_abs_m, p_value, min_neighbours, monroy2018_threshold, full=False,
    )[3]


def mark_reliable(
    rgb: np.ndarray,
    depth_m: np.ndarray,
    known: np.ndarray,
    method: str = "noise_model",
    *,
    dark: float = 0.05,
    bright: float = 0.95,
    noise_rel: float = 0.01,
    noise_abs_m: float = 0.0,
    p_value: float = 0.05,
    min_neighbours: int | None = None,
    monroy2018_threshold: float = MONROY2018_THRESHOLD,
) -> np.ndarray:
    """Mark the pixels of an RGB-D frame that are reliable for colour pairing (paper 003 §5.2).

    Args:
        rgb: (H, W, 3) float linear RGB, nominally in [0, 1] (values outside count as dark / bright).
        depth_m: (H, W) float z-depth in metres; read only where ``known``.
        known: (H, W) bool, the pixels with measured depth (confidence ≥ 0.7), before hole filling.
        method: depth-discontinuity test, one of :data:`RELIABILITY_METHODS`: ``"noise_model"``
            (default, a χ² plane-fit test derived from the ToF noise model) or ``"monroy2018"`` (the
            authors' Σ (d_i − d)² / d > 14.07 with d in metres).
        dark, bright: the exposure rule's thresholds (paper: 0.05, 0.95; strict comparisons).
        noise_rel, noise_abs_m: σ_z = noise_abs_m + noise_rel · z of the depth sensor (``noise_model``;
            the simulated Tango ToF: 0.01, 0).
        p_value: false-rejection probability per pixel on a plane (``noise_model``).
        min_neighbours: pixels with fewer known 8-neighbours than min(``min_neighbours``, their
            in-image neighbours) are unreliable. None: 8 for ``noise_model`` (every in-image
            neighbour known: a dropout next to a pixel may hide an edge), 0 for ``monroy2018``.
        monroy2018_threshold: the threshold of ``monroy2018``.

    Returns:
        (H, W) bool, True where the pixel is known, finite, well exposed and passes the test.

    Raises:
        ShapeError: the shapes disagree. DTypeError: ``known`` is not bool or rgb / depth not float.
        UnknownMethodError: ``method`` is not registered. RangeError: a parameter is out of range
        (DTypeError if ``min_neighbours`` is not an integer).
    """
    depth_m, known, rgb = _check_inputs(depth_m, known, rgb)
    dark, bright = _check_exposure_thresholds(dark, bright)
    return _run(
        depth_m, known, rgb, method, noise_rel, noise_abs_m, p_value, min_neighbours, monroy2018_threshold,
        dark, bright, full=False,
    )[3]
