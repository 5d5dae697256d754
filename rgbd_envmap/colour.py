"""Colour at the sensor boundary (NV21 decoding, the sRGB transfer functions) and the colour-correction
matrix of paper 003 §5 (:func:`estimate_ccm`, :func:`apply_ccm`, :func:`invert_ccm`).

Inside the pipeline colour is linear RGB float32; sRGB-encoded 8-bit only at the sensor (NV21 / PNG).

References:
    IEC 61966-2-1:1999, Multimedia systems – Colour measurement – Default RGB colour space – sRGB.
    Android ``ImageFormat.NV21``: Y plane followed by interleaved V/U at half resolution (ITU-R BT.601,
    decoded here with OpenCV's ``COLOR_YUV2RGB_NV21``).
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
from functools import lru_cache

import cv2
import numba
import numpy as np

from rgbd_envmap.checks import check_array, check_method, check_positive_int
from rgbd_envmap.errors import InvalidInputError, NonFiniteError, RangeError, ShapeError

__all__ = [
    "decode_nv21",
    "encode_nv21",
    "srgb_to_linear",
    "linear_to_srgb",
    "srgb8_to_linear_lut",
    "CCM_METHODS",
    "SUMS_CCM_METHODS",
    "CCMResult",
    "estimate_ccm",
    "apply_ccm",
    "invert_ccm",
]


def decode_nv21(nv21: np.ndarray, height: int, width: int) -> np.ndarray:
    """Decode an NV21 buffer of shape (H * 3 // 2, W) uint8 (or the same bytes flat) into (H, W, 3)
    uint8 sRGB-encoded RGB."""
    height = check_positive_int(height, "height")
    width = check_positive_int(width, "width")
    if height % 2 or width % 2:
        raise InvalidInputError(f"decode_nv21: height and width must be even, got {height}×{width}")
    buf = check_array(nv21, "nv21", dtype=np.uint8)
    expected = height * 3 // 2 * width
    if buf.shape not in ((expected,), (height * 3 // 2, width)):
        raise ShapeError(
            f"nv21: expected shape ({height * 3 // 2}, {width}) or ({expected},) for {height}×{width}, got {buf.shape}"
        )
    return cv2.cvtColor(np.ascontiguousarray(buf.reshape(height * 3 // 2, width)), cv2.COLOR_YUV2RGB_NV21)


def encode_nv21(rgb: np.ndarray) -> np.ndarray:
    """Encode (H, W, 3) uint8 sRGB into an NV21 buffer (H * 3 // 2, W) uint8, the inverse of
    :func:`decode_nv21` up to 4:2:0 chroma subsampling and rounding. OpenCV has no RGB→NV21 encoder,
    so this encodes I420 and interleaves V and U."""
    rgb = check_array(rgb, "rgb", shape=("H", "W", 3), dtype=np.uint8)
    h, w = rgb.shape[:2]
    if h % 2 or w % 2 or h == 0 or w == 0:
        raise InvalidInputError(f"encode_nv21: height and width must be even and > 0, got {h}×{w}")
    i420 = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YUV_I420).reshape(-1)
    y_size, c_size = h * w, (h // 2) * (w // 2)
    out = np.empty(h * 3 // 2 * w, dtype=np.uint8)
    out[:y_size] = i420[:y_size]
    out[y_size::2] = i420[y_size + c_size:]  # V
    out[y_size + 1::2] = i420[y_size:y_size + c_size]  # U
    return out.reshape(h * 3 // 2, w)


@lru_cache(maxsize=1)
def _srgb8_lut() -> np.ndarray:
    lut = srgb_to_linear(np.arange(256, dtype=np.float64) / 255.0).astype(np.float32)
    lut.setflags(write=False)
    return lut


def srgb8_to_linear_lut() -> np.ndarray:
    """(256,) float32 linear value of each 8-bit sRGB code (read-only, cached); ``lut[img]`` decodes
    an image exactly and several times faster than evaluating the transfer function."""
    return _srgb8_lut()


def srgb_to_linear(rgb: np.ndarray) -> np.ndarray:
    """sRGB EOTF (IEC 61966-2-1): encoded values in [0, 1] → linear, float32 (float64 stays float64).

    Values outside [0, 1] are clipped first; NaN stays NaN.
    """
    x = np.asarray(rgb)
    x = np.clip(x.astype(np.float32) if x.dtype.kind != "f" else x, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(x.dtype, copy=False)


def linear_to_srgb(rgb: np.ndarray) -> np.ndarray:
    """Inverse sRGB EOTF: linear values (clipped to [0, 1]) → encoded values in [0, 1]."""
    x = np.asarray(rgb)
    x = np.clip(x.astype(np.float32) if x.dtype.kind != "f" else x, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(x.dtype, copy=False)


# ------------------------------------------------------------------------------------------------
# Colour-correction matrix (paper 003 §5)
# ------------------------------------------------------------------------------------------------

#: Names accepted by :func:`estimate_ccm`'s ``method``. ``"least_squares"`` is this module's single-pass
#: normal-equation solver; the other two call colour-science's ``matrix_colour_correction`` with its
#: 3×3 linear variant (Cheung 2004 with ``terms=3``, Finlayson 2015 root-polynomial ``degree=1``). All
#: three minimise the same objective and agree to rounding on well-conditioned data.
CCM_METHODS: tuple[str, ...] = ("least_squares", "ridge", "Cheung 2004", "Finlayson 2015")
#: The methods fitted from the pairs' normal-equation sums alone (the others need the pairs).
SUMS_CCM_METHODS: tuple[str, ...] = ("least_squares", "ridge")
#: ``estimate_ccm``'s default ``ridge`` weight.
DEFAULT_RIDGE = 0.1

#: Default gate on the condition number of the column-equilibrated 3×3 normal matrix (see
#: :func:`estimate_ccm`). Measured (docs/colour_correction.md): random colours ≈ 10, the 24
#: ColorChecker patches ≈ 20, frames of the simulated office 8–5,000, the six ColorChecker greys with
#: 8-bit-like noise ≈ 3e4 and with 0.5 % noise ≈ 6e4–9e4.
DEFAULT_MAX_CONDITION = 1e4
#: Below this smallest / largest eigenvalue ratio of the equilibrated normal matrix the system counts as
#: numerically rank-deficient (float64 normal equations keep no significant digit along that direction).
_RANK_RTOL = 1e-12
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
    """

    matrix: np.ndarray
    mse: float
    n_pairs: int
    accepted: bool
    reason: str
    method: str
    condition: float = math.nan

    def __post_init__(self) -> None:
        m = check_array(self.matrix, "matrix", shape=(3, 3), dtype=("float", "int"))
        m = np.array(m, dtype=np.float64, copy=True)
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)
        object.__setattr__(self, "mse", float(self.mse))
        object.__setattr__(self, "n_pairs", int(self.n_pairs))
        object.__setattr__(self, "accepted", bool(self.accepted))
        object.__setattr__(self, "condition", float(self.condition))
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
            and (self.n_pairs, self.accepted, self.reason, self.method)
            == (other.n_pairs, other.accepted, other.reason, other.method)
        )

    __hash__ = None  # type: ignore[assignment]


@numba.njit(cache=True, error_model="numpy")
def _ccm_sums(src: np.ndarray, dst: np.ndarray, saturation: float):
    """One pass over (N, 3) src / dst: the normal-equation sums AᵀA, AᵀB and tr(BᵀB) in float64 over
    the rows kept, plus the counts kept / dropped as non-finite / dropped as saturated (any src channel
    ≥ ``saturation``). Scalar accumulators keep the loop in registers."""
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    t00 = t01 = t02 = t10 = t11 = t12 = t20 = t21 = t22 = 0.0
    bb = 0.0
    n = 0
    n_nonfinite = 0
    n_saturated = 0
    for i in range(src.shape[0]):
        a0 = np.float64(src[i, 0])
        a1 = np.float64(src[i, 1])
        a2 = np.float64(src[i, 2])
        b0 = np.float64(dst[i, 0])
        b1 = np.float64(dst[i, 1])
        b2 = np.float64(dst[i, 2])
        if not (
            math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)
            and math.isfinite(b0) and math.isfinite(b1) and math.isfinite(b2)
        ):
            n_nonfinite += 1
            continue
        if a0 >= saturation or a1 >= saturation or a2 >= saturation:
            n_saturated += 1
            continue
        n += 1
        s00 += a0 * a0
        s01 += a0 * a1
        s02 += a0 * a2
        s11 += a1 * a1
        s12 += a1 * a2
        s22 += a2 * a2
        t00 += a0 * b0
        t01 += a0 * b1
        t02 += a0 * b2
        t10 += a1 * b0
        t11 += a1 * b1
        t12 += a1 * b2
        t20 += a2 * b0
        t21 += a2 * b1
        t22 += a2 * b2
        bb += b0 * b0 + b1 * b1 + b2 * b2
    ata = np.empty((3, 3))
    ata[0, 0], ata[0, 1], ata[0, 2] = s00, s01, s02
    ata[1, 0], ata[1, 1], ata[1, 2] = s01, s11, s12
    ata[2, 0], ata[2, 1], ata[2, 2] = s02, s12, s22
    atb = np.empty((3, 3))
    atb[0, 0], atb[0, 1], atb[0, 2] = t00, t01, t02
    atb[1, 0], atb[1, 1], atb[1, 2] = t10, t11, t12
    atb[2, 0], atb[2, 1], atb[2, 2] = t20, t21, t22
    return ata, atb, bb, n, n_nonfinite, n_saturated


@numba.njit(cache=True)
def _sym3_eigh(a):  # pragma: no cover - compiled
    """Eigenvalues (ascending) and eigenvectors (columns) of a symmetric 3×3 matrix by cyclic Jacobi
    rotations, each zeroing one off-diagonal entry (quadratic convergence: 4–6 sweeps). Written out
    rather than numba's LAPACK wrappers, whose compilation took 19 s on a fresh machine; small
    eigenvalues of positive semi-definite matrices come out with high relative accuracy."""
    m = a.copy()
    v = np.eye(3)
    for _ in range(60):
        off = m[0, 1] * m[0, 1] + m[0, 2] * m[0, 2] + m[1, 2] * m[1, 2]
        diag = m[0, 0] * m[0, 0] + m[1, 1] * m[1, 1] + m[2, 2] * m[2, 2]
        if not off > 1e-36 * diag:  # also ends on NaN
            break
        for p, q, r in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            apq = m[p, q]
            if apq == 0.0:
                continue
            theta = (m[q, q] - m[p, p]) / (2.0 * apq)
            t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
            t = -t if theta < 0.0 else t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            m[p, p] -= t * apq
            m[q, q] += t * apq
            m[p, q] = m[q, p] = 0.0
            arp, arq = m[r, p], m[r, q]
            m[r, p] = m[p, r] = c * arp - s * arq
            m[r, q] = m[q, r] = s * arp + c * arq
            for k in range(3):
                vkp, vkq = v[k, p], v[k, q]
                v[k, p] = c * vkp - s * vkq
                v[k, q] = s * vkp + c * vkq
    w = np.array([m[0, 0], m[1, 1], m[2, 2]])
    # Ascending by insertion, as numba's argsort orders three values (its sort cost 1.7 s of
    # compile on a first run); the sums reaching here are finite.
    i0, i1, i2 = 0, 1, 2
    if w[i1] < w[i0]:
        i0, i1 = i1, i0
    if w[i2] < w[i1]:
        i1, i2 = i2, i1
        if w[i1] < w[i0]:
            i0, i1 = i1, i0
    order = np.array([i0, i1, i2])
    return w[order], v[:, order]


@numba.njit(cache=True)
def _equilibrated(ata):  # pragma: no cover - compiled
    """(d, condition, eigenvalues, eigenvectors of C) with ata = diag(d) C diag(d) and C's
    diagonal 1 (zero columns keep d = 1). The condition number of C is invariant to per-channel
    gains of src, i.e. to exposure and white balance, so one threshold serves every frame."""
    d = np.empty(3)
    for i in range(3):
        d[i] = math.sqrt(ata[i, i]) if ata[i, i] > 0.0 else 1.0
    c = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            c[i, j] = ata[i, j] / (d[i] * d[j])
    w, v = _sym3_eigh(c)
    cond = math.inf if w[0] <= _RANK_RTOL * w[2] else w[2] / w[0]
    return d, cond, w, v


@numba.njit(cache=True)
def _eigen_solve(w, v, rhs, rtol):  # pragma: no cover - compiled
    """V diag(1/w) Vᵀ rhs, eigenvalues at or below rtol · the largest taken as zero (the
    pseudo-inverse, i.e. the minimum-norm solution, when the matrix is singular)."""
    inv = np.zeros(3)
    for i in range(3):
        if w[i] > rtol * w[2]:
            inv[i] = 1.0 / w[i]
    out = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += v[i, k] * inv[k] * (v[0, k] * rhs[0, j] + v[1, k] * rhs[1, j] + v[2, k] * rhs[2, j])
            out[i, j] = acc
    return out


@numba.njit(cache=True)
def _fit_sums(ata, atb, bb, n, ridge):  # pragma: no cover - compiled
    """The fit of :func:`estimate_ccm` from its sums: (matrix, mse, condition, well posed), in one
    compiled call (as numpy 3×3 operations it cost 0.34 ms a frame in the main job, 0.12 compiled).
    ``ridge`` < 0: plain least squares through the column-equilibrated normal equations, the
    pseudo-inverse (minimum-norm solution) when they are not well posed, as a best effort;
    ``ridge`` > 0: the ridge fit, whose conditioning gate applies to the regularised system (rank
    deficiency of the data itself still counts). Solves go through the Jacobi eigendecomposition
    (:func:`_sym3_eigh`); the matrices agree with LAPACK's solve to rounding (tests)."""
    d, cond, w, v = _equilibrated(ata)
    well_posed = math.isfinite(cond)
    lam = ridge * (ata[0, 0] + ata[1, 1] + ata[2, 2]) / 3.0
    if lam > 0.0:
        reg = ata.copy()
        rhs = atb.copy()
        for i in range(3):
            reg[i, i] += lam
            rhs[i, i] += lam * atb[i, i] / max(ata[i, i], 1e-300)
        cond = _equilibrated(reg)[1]
        wr, vr = _sym3_eigh(reg)
        x = _eigen_solve(wr, vr, rhs, 0.0)
        well_posed = well_posed and math.isfinite(cond)
    else:
        rhs = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                rhs[i, j] = atb[i, j] / d[i]
        y = _eigen_solve(w, v, rhs, _RANK_RTOL)
        x = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                x[i, j] = y[i, j] / d[i]
    sse = bb
    for i in range(3):
        for j in range(3):
            xax = 0.0
            for k in range(3):
                xax += ata[i, k] * x[k, j]
            sse += x[i, j] * (xax - 2.0 * atb[i, j])
    mse = max(sse, 0.0) / (3.0 * n) if math.isfinite(sse) else math.nan
    return x.T.copy(), mse, cond, well_posed


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
       the signal reach κ of a few hundred and pass gate 3 (docs/colour_correction.md);
    5. a non-finite matrix or MSE: ``"non-finite (...)"``;
    6. ``mse > max_mse``: ``"mse 0.08 > 0.05"``.

    A rejected result still carries a best-effort matrix (the minimum-norm fit when at least three
    finite pairs exist and the sums are finite, else the identity with ``mse`` NaN); callers must keep
    their previous accepted matrix (§5.2: do not project the frame into the EM either). Bad data
    content never raises.

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

    Returns:
        :class:`CCMResult`.

    Raises:
        ShapeError: src or dst not (..., 3), or their shapes differ.
        DTypeError: a non-float array.
        UnknownMethodError: ``method`` not in :data:`CCM_METHODS`.
        RangeError: a negative or NaN ``max_mse``, ``max_condition`` < 1, ``min_pairs`` < 1, a NaN
            ``saturation``, or a negative or non-finite ``noise_std``.

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
    max_mse = float(max_mse)
    if not max_mse >= 0.0:
        raise RangeError(f"max_mse: expected a number ≥ 0, got {max_mse}")
    max_condition = float(max_condition)
    if not max_condition >= 1.0:
        raise RangeError(f"max_condition: expected a number ≥ 1, got {max_condition}")
    min_pairs = check_positive_int(min_pairs, "min_pairs")
    sat = math.inf if saturation is None else float(saturation)
    if math.isnan(sat):
        raise RangeError("saturation: expected a number or None, got nan")
    if noise_std is not None:
        noise_std = float(noise_std)
        if not 0.0 <= noise_std < math.inf:
            raise RangeError(f"noise_std: expected a finite number ≥ 0 or None, got {noise_std}")
    if not float(ridge) >= 0.0:
        raise RangeError(f"ridge: expected a number ≥ 0, got {ridge}")
    a = _check_ccm_input(src_raw, "src")
    b = _check_ccm_input(dst_raw, "dst")
    return _ccm_from_sums(*_ccm_sums(a, b, sat), method, max_mse=max_mse, min_pairs=min_pairs,
                          max_condition=max_condition, noise_std=noise_std, ridge=float(ridge), data=(a, b, sat))


def _ccm_from_sums(
    ata: np.ndarray, atb: np.ndarray, bb: float, n: int, n_nonfinite: int, n_saturated: int, method: str, *,
    max_mse: float, min_pairs: int, max_condition: float, noise_std: float | None, ridge: float,
    data: tuple[np.ndarray, np.ndarray, float] | None = None,
) -> CCMResult:
    """:func:`estimate_ccm` from the normal-equation sums of its pairs (:func:`_ccm_sums`, or the map's
    fused pair pass), the arguments already checked. ``data`` = (src, dst, saturation) is needed by
    the colour-science methods only, which fit the pairs themselves."""
    need = max(min_pairs, _MIN_SOLVABLE_PAIRS)
    identity = np.eye(3)

    def result(matrix: np.ndarray, mse: float, reason: str, cond: float = math.nan) -> CCMResult:
        return CCMResult(matrix, mse, n, not reason, reason, method, cond)

    sums_finite = bool(np.isfinite(ata).all() and np.isfinite(atb).all() and math.isfinite(bb))
    if n < _MIN_SOLVABLE_PAIRS or not sums_finite:
        if n < need:
            return result(identity, math.nan, _too_few(n, need, n_nonfinite, n_saturated))
        return result(identity, math.nan, "non-finite (normal equations overflow)")

    if method in SUMS_CCM_METHODS:
        # ridge = 0 (no pull towards the diagonal) is plain least squares.
        matrix, mse, cond, well_posed = _fit_sums(ata, atb, bb, n, ridge if method == "ridge" else -1.0)
    else:
        if data is None:
            raise InvalidInputError(f"method {method!r} fits the pairs themselves: pass them (estimate_ccm)")
        cond = _equilibrated(ata)[1]
        well_posed = math.isfinite(cond)
        a, b, sat = data
        a_k, b_k = a.astype(np.float64), b.astype(np.float64)
        if n < len(a):  # the same rows the kernel kept
            keep = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1) & ~(a >= sat).any(axis=1)
            a_k, b_k = a_k[keep], b_k[keep]
        with np.errstate(all="ignore"):
            matrix = _matrix_colour_science(method, a_k, b_k)
            mse = float(np.mean((a_k @ matrix.T - b_k) ** 2))

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
