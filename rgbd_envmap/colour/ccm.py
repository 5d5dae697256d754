"""The colour-correction matrix of paper 003 §5: :func:`estimate_ccm` fits it from paired colours
and gates it, :func:`ccm_from_sums` does the same from the pairs' normal-equation sums (the capture
accumulates them in the pair pass), :func:`apply_ccm` applies it and :func:`invert_ccm` inverts it.
Where the frame's exposure relative to the reference's is known, both fits take it as ``known_gain``:
the fitted matrix keeps its white balance and channel mixing, and its overall gain is set to the known
one, so a change of the scene's light is not taken for an exposure change.

Colours are linear RGB. The least-squares fit, its ridge variant and the gate are documented at
:func:`estimate_ccm`; the compiled sums and 3×3 solve are in :mod:`rgbd_envmap._kernels.ccm`, and
:func:`rgbd_envmap.reference.colour.ccm_least_squares_reference` is the same fit in plain numpy.

References:
    Monroy, Hudon, Smolic (2018), Dynamic Environment Mapping for Augmented Reality Applications on
    Mobile Devices, §5.1 (correction matrix to the first frame's colour space, after Rohmer et al. 2017),
    §5.2 (paired samples, MSE threshold 5e-2) and §7.2 (inverse matrix for compositing).
    Cheung, Westland, Connah, Ripamonti (2004), A comparative study of the characterisation of colour
    cameras by means of neural networks and polynomial transforms, Coloration Technology 120(1), 19–25.
    Finlayson, Mackiewicz, Hurlbert (2015), Color Correction Using Root-Polynomial Regression, IEEE
    Transactions on Image Processing 24(5), 1460–1470.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rgbd_envmap._kernels import ccm as kernels
from rgbd_envmap.checks import check_array, check_method, check_number, check_positive_int
from rgbd_envmap.errors import InvalidInputError, NonFiniteError, RangeError, ShapeError

__all__ = [
    "CCM_METHODS",
    "SUMS_CCM_METHODS",
    "GAIN_CHANNELS",
    "DEFAULT_RIDGE",
    "DEFAULT_MAX_CONDITION",
    "MIN_SPREAD_SNR",
    "CCMResult",
    "estimate_ccm",
    "ccm_sums",
    "ccm_from_sums",
    "matrix_gain",
    "apply_ccm",
    "invert_ccm",
]

#: Names accepted by :func:`estimate_ccm`'s ``method``. ``"least_squares"`` is this module's single-pass
#: normal-equation solver; the other two call colour-science's ``matrix_colour_correction`` with its
#: 3×3 linear variant (Cheung 2004 with ``terms=3``, Finlayson 2015 root-polynomial ``degree=1``). All
#: three minimise the same objective and agree to rounding on well-conditioned data.
CCM_METHODS: tuple[str, ...] = ("least_squares", "ridge", "Cheung 2004", "Finlayson 2015")
#: The methods fitted from the pairs' normal-equation sums alone (the others need the pairs).
SUMS_CCM_METHODS: tuple[str, ...] = ("least_squares", "ridge")
#: Names accepted by ``gain_channel``: which response of the matrix to grey, ``M·(1, 1, 1)ᵀ``, is its
#: overall gain (the one ``known_gain`` sets). ``"green"``: the green channel's; a camera's white balance
#: keeps the green gain at 1 (the simulated camera's does, as most ISPs and DNG's AsShotNeutral), so
#: with the exposure divided out the true matrix has a green gain of exactly 1. ``"luminance"``: the
#: Rec. 709 luminance of that response, exact only when the white balance does not move luminance.
GAIN_CHANNELS: tuple[str, ...] = ("green", "luminance")
_GAIN_WEIGHTS = {"green": np.array([0.0, 1.0, 0.0]), "luminance": np.array([0.2126, 0.7152, 0.0722])}
#: ``estimate_ccm``'s default ``ridge`` weight.
DEFAULT_RIDGE = 0.1

#: Default gate on the condition number of the column-equilibrated 3×3 normal matrix (see
#: :func:`estimate_ccm`). Measured (docs/design/colour_correction.md): random colours ≈ 10, the 24
#: ColorChecker patches ≈ 20, frames of the simulated office 8–5,000, the six ColorChecker greys with
#: 8-bit-like noise ≈ 3e4 and with 0.5 % noise ≈ 6e4–9e4.
DEFAULT_MAX_CONDITION = 1e4
#: With ``noise_std`` given, the mean square of the samples along their weakest colour direction must
#: exceed this many times ``noise_std²``; errors in src attenuate the fitted matrix along that direction
#: by about noise_std² / (that mean square), so 10 bounds the attenuation near 10 %.
MIN_SPREAD_SNR = 10.0
#: A 3×3 matrix with 2-norm condition number above this is treated as singular by :func:`invert_ccm`.
_INVERT_MAX_CONDITION = 1e12
#: A 3×3 linear fit needs at least three pairs whatever ``min_pairs`` says.
_MIN_SOLVABLE_PAIRS = 3


@dataclass(frozen=True, eq=False)
class CCMResult:
    """Outcome of :func:`estimate_ccm`.

    Attributes:
        matrix: (3, 3) float64, read-only; corrected colours are ``src @ matrix.T`` (``dst ≈ src @
            matrix.T``). For a rejected result this is a best-effort fit when one could be computed,
            else the identity: callers keep their previous *accepted* matrix instead.
        mse: mean over pairs *and* channels of the squared residual ``(src @ matrix.T − dst)²``, in
            linear RGB units squared (so 5e-2 is an RMS error of 0.22 per channel). NaN when no matrix
            was fitted.
        n_pairs: pairs actually used, after dropping rows with a non-finite value in ``src`` or ``dst``
            and rows with a saturated ``src`` channel.
        accepted: True when the matrix passed every gate.
        reason: ``""`` when accepted, else why not, e.g. ``"too few pairs (12 < 500)"``,
            ``"mse 0.08 > 0.05"``, ``"ill-conditioned (condition number 6.2e+04 > 1e+04)"``,
            ``"rank-deficient (condition number inf)"``, ``"non-finite (...)"``.
        method: the method name that produced ``matrix``.
        condition: condition number of the column-equilibrated normal matrix (NaN when not computed).
        fitted_gain: with ``known_gain``, the overall gain (:func:`matrix_gain`) of the free fit, which
            ``matrix`` replaced by the known one: fitted / known is the map's brightness over the
            frame's at the same surfaces, the exposure divided out (1: the scene's light did not
            change; 2.5: the room darkened to 40 % since the map saw it). None without ``known_gain``,
            and when no finite matrix was fitted.
    """

    matrix: np.ndarray
    mse: float
    n_pairs: int
    accepted: bool
    reason: str
    method: str
    condition: float = math.nan
    fitted_gain: float | None = None

    def __post_init__(self) -> None:
        m = check_array(self.matrix, "matrix", shape=(3, 3), dtype=("float", "int"))
        m = np.array(m, dtype=np.float64, copy=True)
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)
        object.__setattr__(self, "mse", float(self.mse))
        object.__setattr__(self, "n_pairs", int(self.n_pairs))
        object.__setattr__(self, "accepted", bool(self.accepted))
        object.__setattr__(self, "condition", float(self.condition))
        if self.fitted_gain is not None:
            object.__setattr__(self, "fitted_gain", float(self.fitted_gain))
        if self.accepted == bool(self.reason):
            raise InvalidInputError(
                f"CCMResult: reason must be empty exactly when accepted, got accepted={self.accepted}, "
                f"reason={self.reason!r}"
            )

    def __eq__(self, other: object) -> bool:
        if type(other) is not CCMResult:
            return NotImplemented
        return (
            np.array_equal(self.matrix, other.matrix, equal_nan=True)
            and (self.mse == other.mse or (math.isnan(self.mse) and math.isnan(other.mse)))
            and (self.condition == other.condition or (math.isnan(self.condition) and math.isnan(other.condition)))
            and self.fitted_gain == other.fitted_gain
            and (self.n_pairs, self.accepted, self.reason, self.method)
            == (other.n_pairs, other.accepted, other.reason, other.method)
        )

    __hash__ = None  # type: ignore[assignment]


def _matrix_colour_science(method: str, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    import colour as colour_science  # colour-science; imported lazily (slow import), name clash with us

    kwargs = {"terms": 3} if method == "Cheung 2004" else {"degree": 1, "root_polynomial_expansion": True}
    # M_T is the test (to be corrected) array, M_R the reference; the result maps M_T onto M_R as
    # M_R ≈ M_T @ matrix.T, our convention with src = M_T and dst = M_R.
    with np.errstate(all="ignore"):
        return np.asarray(
            colour_science.characterisation.matrix_colour_correction(M_T=src, M_R=dst, method=method, **kwargs),
            dtype=np.float64,
        )


def _check_ccm_input(value: object, name: str) -> np.ndarray:
    arr = check_array(value, name, shape=("*", 3), dtype="float")
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float64)
    return np.ascontiguousarray(arr.reshape(-1, 3))


def estimate_ccm(
    src: np.ndarray,
    dst: np.ndarray,
    method: str = "least_squares",
    *,
    max_mse: float = 5e-2,
    min_pairs: int = 500,
    max_condition: float = DEFAULT_MAX_CONDITION,
    saturation: float | None = 1.0,
    noise_std: float | None = None,
    ridge: float = DEFAULT_RIDGE,
    known_gain: float | None = None,
    gain_channel: str = "green",
) -> CCMResult:
    """Fit the 3×3 colour-correction matrix M with ``dst ≈ src @ M.T`` and gate it (paper 003 §5).

    ``method="ridge"`` is the same least squares pulled towards the per-channel (von Kries) diagonal
    fit d_c = Σ src_c dst_c / Σ src_c²: it minimises ‖src Mᵀ − dst‖² + λ‖M − diag(d)‖² with
    λ = ``ridge`` · tr(AᵀA) / 3. Along colour directions the samples span well the data decide; along
    the ones they barely span (grey-dominated rooms, where plain least squares fits the noise and
    returns a desaturating matrix) the fit falls back to exposure × white balance. Its conditioning
    gate applies to the regularised system.

    ``src`` are the current frame's colours, ``dst`` the paired reference colours (the EM, i.e. the
    first frame's colour space). The fit is ordinary least squares without offset,
    M = argmin ‖src Mᵀ − dst‖²_F, which models exposure × white balance × mild channel mixing. The
    default method accumulates AᵀA, AᵀB and tr(BᵀB) in float64 in one numba pass (single thread) and
    solves the column-equilibrated 3×3 normal equations; the MSE comes from the same sums, with no
    second pass.

    Rows are dropped, not rejected: a pair with any non-finite value (NaN / inf in src or dst), and a
    pair whose src has a channel ≥ ``saturation`` (a clipped channel only bounds the true value from
    below and would pull the fit towards the clip level). ``dst`` is never filtered by value: the EM is
    unbounded above, and selecting pairs on the regressand would bias the fit.

    The gate (§5.2 and the authors' implementation) rejects, in this order, with ``accepted=False`` and
    a ``reason``:

    1. fewer than ``max(min_pairs, 3)`` pairs kept: ``"too few pairs (n < min)"``;
    2. normal-equation sums that overflowed: ``"non-finite (...)"``;
    3. the condition number κ of the column-equilibrated normal matrix D⁻¹AᵀAD⁻¹ (D² = diag AᵀA)
       above ``max_condition``: ``"ill-conditioned (...)"``, or ``"rank-deficient (...)"`` when κ ≥
       1e12. κ is invariant to per-channel gains; ``1/√κ`` is the RMS spread of the samples along the
       least-populated colour direction relative to the strongest. Grey-only or single-colour samples
       give κ ≫ 1e4: the matrix is then fixed by noise along the chroma directions (attenuated towards
       a desaturating matrix whose inverse over-saturates the composited object) while the MSE stays
       small, so the MSE gate alone would accept it;
    4. only when ``noise_std`` is given: the mean square λ of the samples along their weakest colour
       direction (smallest eigenvalue of AᵀA / n, src units²) below :data:`MIN_SPREAD_SNR` ×
       ``noise_std²``: ``"weak colour spread (...)"``. κ alone cannot tell colour spread from noise
       spread: dark grey-only or single-colour samples whose additive noise is a sizeable fraction of
       the signal reach κ of a few hundred and pass gate 3 (docs/design/colour_correction.md);
    5. a non-finite matrix or MSE: ``"non-finite (...)"``;
    6. ``mse > max_mse``: ``"mse 0.08 > 0.05"``.

    A rejected result still carries a best-effort matrix (the minimum-norm fit when at least three
    finite pairs exist and the sums are finite, else the identity with ``mse`` NaN); callers must keep
    their previous accepted matrix (§5.2: do not project the frame into the EM either). Bad data
    content never raises.

    Known exposure (docs/design/colour_correction.md): with ``known_gain`` g (the reference frame's
    exposure over this frame's, exposure time × ISO), the fitted matrix M⁰ keeps its white balance and
    channel mixing and takes the known gain: M = g · M⁰ / G(M⁰), G = :func:`matrix_gain` along
    ``gain_channel``. A change of the scene's light by a neutral factor k since the map saw it scales
    the free fit by 1/k in every channel, and this undoes it exactly; the result records G(M⁰) as
    ``fitted_gain``. The gates and the MSE are the free fit's (whether the pairs agree under some
    3×3 matrix; the residual of M itself holds the light change, which is the map's to take); a free
    fit whose G is not > 0 and finite is rejected, ``"gain ... not > 0 and finite"``.

    Args:
        src: (..., 3) float linear RGB of the current frame; leading axes are flattened.
        dst: (..., 3) float linear RGB reference colours, same shape as ``src``.
        method: one of :data:`CCM_METHODS`.
        max_mse: MSE gate (paper: 5e-2), in linear units squared, mean over pairs and channels.
        min_pairs: fewest pairs kept for acceptance (authors' implementation: 500).
        max_condition: gate on κ (default :data:`DEFAULT_MAX_CONDITION` = 1e4).
        saturation: src channel level at or above which a pair is dropped; None keeps every pair.
        noise_std: per-channel standard deviation of the noise in src, linear units (e.g. from the
            sensor model); None (default) skips gate 4.
        ridge: the ridge weight λ of ``method="ridge"``, relative to tr(AᵀA) / 3.
        known_gain: None (default: the gain is fitted, the paper), or the matrix's overall gain, a
            finite number > 0.
        gain_channel: one of :data:`GAIN_CHANNELS`, used with ``known_gain``.

    Returns:
        :class:`CCMResult`.

    Raises:
        ShapeError: src or dst not (..., 3), or their shapes differ.
        DTypeError: a non-float array.
        UnknownMethodError: ``method`` not in :data:`CCM_METHODS`, or ``gain_channel`` not in
            :data:`GAIN_CHANNELS`.
        RangeError: a negative or NaN ``max_mse``, ``max_condition`` < 1, ``min_pairs`` < 1, a NaN
            ``saturation``, a negative or non-finite ``noise_std``, or a ``known_gain`` not > 0 and finite.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> src = rng.random((1000, 3)).astype(np.float32)
        >>> gains = np.diag([0.5, 1.0, 2.0])
        >>> r = estimate_ccm(src, src @ gains.T)
        >>> bool(r.accepted), np.allclose(r.matrix, gains, atol=1e-5), r.n_pairs
        (True, True, 1000)
    """
    check_method(method, CCM_METHODS)
    src_raw = check_array(src, "src", shape=("*", 3), dtype="float")
    dst_raw = check_array(dst, "dst", shape=("*", 3), dtype="float")
    if src_raw.shape != dst_raw.shape:
        raise ShapeError(f"dst: expected the shape of src {src_raw.shape}, got {dst_raw.shape}")
    max_mse = check_number(max_mse, "max_mse", low=0.0)
    max_condition = check_number(max_condition, "max_condition", low=1.0)
    min_pairs = check_positive_int(min_pairs, "min_pairs")
    sat = math.inf if saturation is None else _check_saturation(saturation)
    noise_std = check_number(noise_std, "noise_std", low=0.0, optional=True)
    ridge = check_number(ridge, "ridge", low=0.0)
    known_gain, gain_channel = _check_known_gain(known_gain, gain_channel)
    a = _check_ccm_input(src_raw, "src")
    b = _check_ccm_input(dst_raw, "dst")
    return ccm_from_sums(*kernels.ccm_sums(a, b, sat), method, max_mse=max_mse, min_pairs=min_pairs,
                         max_condition=max_condition, noise_std=noise_std, ridge=float(ridge), data=(a, b, sat),
                         known_gain=known_gain, gain_channel=gain_channel)


def _check_known_gain(known_gain: object, gain_channel: object = "green") -> tuple[float | None, str]:
    """``(known_gain, gain_channel)`` of :func:`estimate_ccm`, checked: None or a finite number > 0,
    and one of :data:`GAIN_CHANNELS`."""
    check_method(gain_channel, GAIN_CHANNELS, "gain_channel")
    if known_gain is None:
        return None, gain_channel
    g = float(check_number(known_gain, "known_gain", low=0.0, low_open=True))
    if not math.isfinite(g):
        raise RangeError(f"known_gain: expected a finite number > 0, got {g}")
    return g, gain_channel


def matrix_gain(matrix: np.ndarray, gain_channel: str = "green") -> float:
    """The overall gain of a correction matrix: wᵀ·M·(1, 1, 1)ᵀ, its response to grey along
    ``gain_channel`` (:data:`GAIN_CHANNELS`: the green channel's, or its Rec. 709 luminance). For
    exposure × white balance, diag(e·r, e, e·b), the green gain is e."""
    check_method(gain_channel, GAIN_CHANNELS, "gain_channel")
    m = _check_ccm_matrix(matrix)
    return float(_GAIN_WEIGHTS[gain_channel] @ m.sum(axis=1))


def _check_saturation(saturation: object) -> float:
    """A saturation level: a number > 0, infinity allowed (nothing saturates)."""
    if isinstance(saturation, (float, np.floating)) and saturation == math.inf:
        return math.inf
    return float(check_number(saturation, "saturation", low=0.0, low_open=True))


def ccm_sums(src: np.ndarray, dst: np.ndarray, saturation: float) -> tuple:
    """The normal-equation sums of the pairs (src, dst), as :func:`estimate_ccm` accumulates them:
    ``(AᵀA, AᵀB, tr(BᵀB), kept, dropped non-finite, dropped saturated)``, the sums in float64 over the
    rows kept (pair order), a row dropped when any value is non-finite or any src channel is ≥
    ``saturation`` (a number > 0, or infinity). ``src`` and ``dst`` are (N, 3) float arrays of one
    shape (float16 converted). :func:`ccm_from_sums` fits and gates the matrix from them."""
    src_raw = check_array(src, "src", shape=("*", 3), dtype="float")
    dst_raw = check_array(dst, "dst", shape=("*", 3), dtype="float")
    if src_raw.shape != dst_raw.shape:
        raise ShapeError(f"dst: expected the shape of src {src_raw.shape}, got {dst_raw.shape}")
    return kernels.ccm_sums(_check_ccm_input(src_raw, "src"), _check_ccm_input(dst_raw, "dst"), _check_saturation(saturation))


def ccm_from_sums(
    ata: np.ndarray, atb: np.ndarray, bb: float, n: int, n_nonfinite: int, n_saturated: int, method: str, *,
    max_mse: float, min_pairs: int, max_condition: float, noise_std: float | None, ridge: float,
    data: tuple[np.ndarray, np.ndarray, float] | None = None, known_gain: float | None = None,
    gain_channel: str = "green",
) -> CCMResult:
    """:func:`estimate_ccm` from the normal-equation sums of its pairs (:func:`ccm_sums`, or the map's
    fused pair pass), the arguments already checked (``known_gain``, ``gain_channel``:
    :func:`_check_known_gain`). ``data`` = (src, dst, saturation) is needed by the colour-science
    methods only, which fit the pairs themselves."""
    need = max(min_pairs, _MIN_SOLVABLE_PAIRS)
    identity = np.eye(3)
    fitted_gain: float | None = None

    def result(matrix: np.ndarray, mse: float, reason: str, cond: float = math.nan) -> CCMResult:
        return CCMResult(matrix, mse, n, not reason, reason, method, cond, fitted_gain)

    sums_finite = bool(np.isfinite(ata).all() and np.isfinite(atb).all() and math.isfinite(bb))
    if n < _MIN_SOLVABLE_PAIRS or not sums_finite:
        if n < need:
            return result(identity, math.nan, _too_few(n, need, n_nonfinite, n_saturated))
        return result(identity, math.nan, "non-finite (normal equations overflow)")

    if method in SUMS_CCM_METHODS:
        # ridge = 0 (no pull towards the diagonal) is plain least squares.
        matrix, mse, cond, well_posed = kernels.fit_sums(ata, atb, bb, n, ridge if method == "ridge" else -1.0)
    else:
        if data is None:
            raise InvalidInputError(f"method {method!r} fits the pairs themselves: pass them (estimate_ccm)")
        cond = kernels.equilibrated(ata)[1]
        well_posed = math.isfinite(cond)
        a, b, sat = data
        a_k, b_k = a.astype(np.float64), b.astype(np.float64)
        if n < len(a):  # the same rows the kernel kept
            keep = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1) & ~(a >= sat).any(axis=1)
            a_k, b_k = a_k[keep], b_k[keep]
        with np.errstate(all="ignore"):
            matrix = _matrix_colour_science(method, a_k, b_k)
            mse = float(np.mean((a_k @ matrix.T - b_k) ** 2))

    gain_ok = True
    if known_gain is not None and np.isfinite(matrix).all():
        g = float(_GAIN_WEIGHTS[gain_channel] @ matrix.sum(axis=1))
        fitted_gain = g if math.isfinite(g) else None
        gain_ok = fitted_gain is not None and g > 0.0
        if gain_ok:
            matrix = matrix * (known_gain / fitted_gain)

    if n < need:
        reason = _too_few(n, need, n_nonfinite, n_saturated)
    elif not well_posed:
        reason = f"rank-deficient (condition number {cond:.2g})"
    elif cond > max_condition:
        reason = f"ill-conditioned (condition number {cond:.2g} > {max_condition:.2g})"
    elif noise_std is not None and (spread := float(np.linalg.eigvalsh(ata)[0]) / n) < MIN_SPREAD_SNR * noise_std**2:
        reason = (
            f"weak colour spread (weakest-direction mean square {spread:.2g} < "
            f"{MIN_SPREAD_SNR:g} × noise_std² = {MIN_SPREAD_SNR * noise_std**2:.2g})"
        )
    elif not (np.isfinite(matrix).all() and math.isfinite(mse)):
        reason = "non-finite (matrix or mse)"
    elif mse > max_mse:
        reason = f"mse {mse:.3g} > {max_mse:.3g}"
    elif not gain_ok:
        reason = f"gain {g:.3g} of the fit not > 0 and finite ({gain_channel})"
    else:
        reason = ""
    if not np.isfinite(matrix).all():
        matrix, mse = identity, math.nan
    return result(matrix, mse, reason, cond)


def _too_few(n: int, need: int, n_nonfinite: int, n_saturated: int) -> str:
    dropped = f"; dropped {n_nonfinite} non-finite, {n_saturated} saturated" if n_nonfinite or n_saturated else ""
    return f"too few pairs ({n} < {need}{dropped})"


def _check_ccm_matrix(matrix: object, name: str = "matrix") -> np.ndarray:
    m = check_array(matrix, name, shape=(3, 3), dtype=("float", "int"))
    if not np.isfinite(m).all():
        raise NonFiniteError(f"{name}: expected finite values, got {m.tolist()}")
    return m.astype(np.float64)


def apply_ccm(rgb: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Correct colours: ``rgb @ matrix.T``.

    Args:
        rgb: (..., 3) float linear RGB (e.g. an (H, W, 3) frame); NaN propagates, nothing is clipped.
        matrix: (3, 3) finite, e.g. :attr:`CCMResult.matrix`, or :func:`invert_ccm` of one.

    Returns:
        (..., 3) of rgb's dtype (float32 stays float32; float16 becomes float32).
    """
    rgb = check_array(rgb, "rgb", shape=("*", 3), dtype="float")
    m = _check_ccm_matrix(matrix)
    dtype = np.float64 if rgb.dtype == np.float64 else np.float32
    flat = rgb.reshape(-1, 3).astype(dtype, copy=False)
    return (flat @ m.T.astype(dtype)).reshape(rgb.shape)


def invert_ccm(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a correction matrix, (3, 3) float64: maps reference-space colours (the EM, the
    shaded virtual object) back into the current frame's colour space for compositing (§7.2).

    Raises:
        InvalidInputError: the matrix is singular (2-norm condition number above 1e12).
        NonFiniteError / ShapeError / DTypeError: not a finite real (3, 3) array.
    """
    m = _check_ccm_matrix(matrix)
    cond = float(np.linalg.cond(m))
    if not cond <= _INVERT_MAX_CONDITION:
        raise InvalidInputError(
            f"matrix: expected an invertible correction matrix, got condition number {cond:.3g} "
            f"(> {_INVERT_MAX_CONDITION:.0e})"
        )
    return np.linalg.inv(m)
