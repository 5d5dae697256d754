"""Band selection: the fewest SH bands whose shading of an object stays within a tolerance
("model only what a scene needs").

With an object's per-vertex transfer vectors T (``rgbd_envmap.prt``) and the environment's radiance
coefficients L, the shading with n bands is S_n = T[:, :n²] L[:n²]; :func:`select_bands` picks the
smallest n whose relative RMS error against all bands is within the tolerance. The error only
involves the tail bands, so a precomputed :class:`TransferGram` G = Tᵀ diag(w) T makes the selection
O(K²) per frame instead of O(V K).

References:
    - P.-P. Sloan, J. Kautz, J. Snyder, "Precomputed Radiance Transfer for Real-Time Rendering in
      Dynamic, Low-Frequency Lighting Environments", SIGGRAPH 2002 (transfer vectors).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_array, check_number, check_positive_int
from rgbd_envmap.errors import DTypeError, InvalidInputError, NonFiniteError, RangeError, ShapeError
from rgbd_envmap.sh.basis import n_bands

__all__ = ["BandSelection", "TransferGram", "select_bands", "transfer_gram"]


@dataclass(frozen=True, eq=False)
class TransferGram:
    """G = Tᵀ diag(w) T of an object's per-vertex transfer vectors, for :func:`select_bands`.

    It depends only on the object (and the vertex weights), so compute it once with
    :func:`transfer_gram`; band selection from it costs O(K²) per frame instead of O(V K).

    Attributes:
        gram: (K, K) float64, read-only; K = bands² of the transfer.
        n_vertices: V, the number of transfer rows it summarises.
    """

    gram: np.ndarray
    n_vertices: int


def transfer_gram(transfer: np.ndarray, weights: np.ndarray | None = None) -> TransferGram:
    """Precompute :class:`TransferGram` from (V, K) transfer vectors (see :func:`select_bands`).

    Args:
        transfer: (V, K) float transfer vectors, V ≥ 1, K = n² (finite).
        weights: optional (V,) non-negative finite vertex weights (e.g. vertex areas); default 1.
    """
    T = _check_transfer(transfer)
    w = _check_weights(weights, T.shape[0])
    T64 = T.astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite input is reported below
        G = T64.T @ (T64 if w is None else T64 * w[:, None])
    if not np.isfinite(G).all():
        raise NonFiniteError("transfer: expected finite values, got NaN or inf (or an overflowing sum)")
    G = 0.5 * (G + G.T)
    G.setflags(write=False)
    return TransferGram(G, int(T.shape[0]))


@dataclass(frozen=True, eq=False)
class BandSelection:
    """Result of :func:`select_bands`.

    Attributes:
        bands: the chosen number of bands n (1 ≤ n ≤ ``max_bands``).
        max_bands: N, the band count of the reference shading.
        errors: (N,) float64, read-only; ``errors[n − 1]`` is the relative RMS error e_n of shading
            with n bands against N bands (so ``errors[N − 1] == 0``).
        tolerance: the tolerance the selection used.
        degenerate: True when the reference shading is zero (see :func:`select_bands`); then every
            error is reported as 0 and one band is chosen.
    """

    bands: int
    max_bands: int
    errors: np.ndarray
    tolerance: float
    degenerate: bool = False


def _check_transfer(transfer: np.ndarray) -> np.ndarray:
    T = check_array(transfer, "transfer", shape=("V", "K"), dtype="float")
    if T.shape[0] == 0:
        raise ShapeError("transfer: expected at least one vertex, got shape (0, K)")
    n = math.isqrt(T.shape[1])
    if n < 1 or n * n != T.shape[1]:
        raise ShapeError(f"transfer: expected n² columns (1, 4, 9, 16, 25, ...), got {T.shape[1]}")
    return T


def _check_weights(weights: np.ndarray | None, n_vertices: int) -> np.ndarray | None:
    if weights is None:
        return None
    w = check_array(weights, "weights", shape=(n_vertices,), dtype=("float", "int"), finite=True)
    if (w < 0).any():
        raise RangeError(f"weights: expected values ≥ 0, got minimum {w.min()}")
    return w.astype(np.float64)


# Relative size under which the reference shading counts as zero (see select_bands).
_ZERO_SHADING = 1e-12


def select_bands(coeffs: np.ndarray, transfer: np.ndarray | TransferGram, tolerance: float = 0.01,
                 max_bands: int | None = None, *, weights: np.ndarray | None = None) -> BandSelection:
    """The fewest SH bands whose shading of an object stays within ``tolerance`` of all bands.

    With per-vertex transfer vectors T (V, K) in the SH convention of :mod:`rgbd_envmap.sh.basis`
    (T_k = ∫ V(ω) max(n·ω, 0) Y_k(ω) dω, see ``rgbd_envmap.prt``) and radiance coefficients L, the
    shading with n bands is S_n = T[:, :n²] L[:n²] (V, 3); the outgoing radiance is (albedo / π) S_n.
    With N = ``max_bands`` the reference is S_N, and the error of n bands is the relative RMS over
    vertices and channels

        e_n = ‖S_n − S_N‖ / ‖S_N‖,   ‖X‖² = Σ_v w_v Σ_c X_vc²   (w_v = 1 unless ``weights``).

    The result is the smallest n with e_n ≤ ``tolerance``. Because S_n − S_N = −Σ_{j≥n} B_j with
    B_j the band-j contribution, e_n only involves the tail; from a :class:`TransferGram`
    G = Tᵀ diag(w) T it is ‖tail‖² = Σ_c L_tail,cᵀ G L_tail,c, computed in O(K²).

    Zero shading guard: if ‖S_N‖ ≤ 1e-12 · Σ_j ‖B_j‖ (a black environment, zero transfer, or bands
    that cancel exactly) there is nothing to resolve; every e_n is reported as 0, one band is chosen
    and ``degenerate`` is set. Otherwise the division is safe (‖S_N‖ > 0).

    ``tolerance = 0`` selects the fewest bands that reproduce S_N exactly, which is N unless the top
    bands contribute nothing (unshadowed transfer T_k = Â_l Y_k(n) has Â_l = 0 for odd l ≥ 3).

    Args:
        coeffs: (n_c², 3) float radiance coefficients (finite), e.g. from :func:`project_equirect`.
        transfer: (V, n_t²) float transfer vectors (V ≥ 1), or a :class:`TransferGram` of them.
        tolerance: largest accepted e_n, ≥ 0 (default 1 %).
        max_bands: N; default min(n_c, n_t). Must not exceed either.
        weights: optional (V,) non-negative vertex weights (with a raw ``transfer`` only; a
            :class:`TransferGram` has them built in).

    Returns:
        :class:`BandSelection`.

    Raises:
        ShapeError: bad shapes (non-square coefficient counts, no vertices). RangeError: negative or
        non-finite tolerance, ``max_bands`` out of range, negative weights. NonFiniteError: NaN or
        infinity in the coefficients, or in the transfer (detected through the result).
        InvalidInputError: ``weights`` given with a :class:`TransferGram`.

    Cost: 35k vertices × 64 transfer columns, 8 bands: see benchmarks/bench_sh.py (a raw transfer
    costs one pass over T per frame; a TransferGram costs microseconds).
    """
    L = check_array(coeffs, "coeffs", shape=("K", 3), dtype=("float", "int"), finite=True).astype(np.float64)
    nb_c = n_bands(L.shape[0])
    tol = check_number(tolerance, "tolerance", low=0.0)
    if isinstance(transfer, TransferGram):
        if weights is not None:
            raise InvalidInputError("weights: a TransferGram already includes its vertex weights; "
                                    "pass weights to transfer_gram instead")
        G = transfer.gram
        nb_t = math.isqrt(G.shape[0])
        T = w = None
    else:
        T = _check_transfer(transfer)
        w = _check_weights(weights, T.shape[0])
        nb_t = math.isqrt(T.shape[1])
        G = None
    if max_bands is None:
        N = min(nb_c, nb_t)
    else:
        N = check_positive_int(max_bands, "max_bands")
        if N > min(nb_c, nb_t):
            raise RangeError(f"max_bands: expected ≤ {min(nb_c, nb_t)} (coeffs have {nb_c} bands, "
                             f"transfer {nb_t}), got {N}")
    L = L[:N * N]
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite transfer is reported below
        tail, band = _tail_energies(L, N, G, T, w)
    if not (np.isfinite(tail).all() and np.isfinite(band).all()):
        raise NonFiniteError("transfer: expected finite values, got NaN or inf (or an overflowing sum)")
    tail = np.maximum(tail, 0.0)
    ref = math.sqrt(tail[0])
    degenerate = ref <= _ZERO_SHADING * float(band.sum())
    if degenerate:
        errors = np.zeros(N)
        bands = 1
    else:
        errors = np.sqrt(tail[1:]) / ref
        errors[-1] = 0.0
        bands = int(np.argmax(errors <= tol)) + 1
    errors.setflags(write=False)
    return BandSelection(bands=bands, max_bands=N, errors=errors, tolerance=tol, degenerate=degenerate)


def _tail_energies(L, N, G, T, w):
    """tail[n] = ‖Σ_{j≥n} B_j‖² for n = 0 … N (tail[0] = ‖S_N‖², tail[N] = 0) and band[j] = ‖B_j‖,
    from the Gram matrix G (when T is None) or from the transfer T directly."""
    if T is None:
        K = N * N
        M = G[:K, :K] * (L @ L.T)  # M[k, j] = G[k, j] Σ_c L[k, c] L[j, c]
        C = np.zeros((K + 1, K + 1))  # C[a, b] = Σ_{k ≥ a, j ≥ b} M[k, j]
        C[:K, :K] = M[::-1, ::-1].cumsum(0).cumsum(1)[::-1, ::-1]
        a = np.arange(N + 1) ** 2  # band j spans rows / columns a[j] … a[j + 1] − 1
        tail = C[a, a]
        block = C[a[:-1], a[:-1]] - C[a[:-1], a[1:]] - C[a[1:], a[:-1]] + C[a[1:], a[1:]]
        band = np.sqrt(np.maximum(block, 0.0))
    else:
        Lt = L.astype(T.dtype)  # float32 transfer: float32 products (BLAS sgemm), float64 sums
        sw = None if w is None else np.sqrt(w)[:, None]
        R = np.zeros((T.shape[0], 3))
        tail = np.zeros(N + 1)
        band = np.zeros(N)
        for j in range(N - 1, -1, -1):  # R = Σ_{i≥j} B_i, built from the top band down
            B = T[:, j * j:(j + 1) ** 2] @ Lt[j * j:(j + 1) ** 2]
            R += B
            Bw, Rw = (B, R) if sw is None else (B * sw, R * sw)
            band[j] = math.sqrt(float(np.vdot(Bw, Bw)))
            tail[j] = float(np.vdot(Rw, Rw))
    return tail, band
