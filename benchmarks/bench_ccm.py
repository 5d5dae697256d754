"""Time the colour-correction matrix (paper Table 1 rows "Compute colour correction matrix" 13.97 ms and
"Calculate MSE" 2.69 ms on an Adreno 510).

    python benchmarks/bench_ccm.py [--repeats N] [--n-pairs N] [--json PATH]

38,528 pairs by default (= 224 × 172, every pixel of a Tango RGB-D frame paired), float32 linear RGB as
the pipeline holds it. One thread: numba's pool is set to 1 and BLAS / OpenMP are pinned to one thread
before numpy loads. Rows:

- ``estimate_ccm least_squares``: the library call, numba single-pass normal equations + gate + MSE;
- ``  numba sums only``: the one-pass kernel alone;
- ``numpy normal equations + MSE`` / ``numpy lstsq + MSE``: the same fit written plainly with numpy
  (finite and saturation masks, float64 cast, AᵀA / lstsq, residual MSE), and a ``tuned`` numpy
  version (see :func:`_numpy_tuned`): the alternatives the numba kernel was measured against;
- ``estimate_ccm 'Cheung 2004'`` / ``'Finlayson 2015'``: the library call dispatching to colour-science
  (masks + kernel for the gate + colour-science fit + residual MSE);
- ``colour-science matrix_colour_correction``: colour-science alone, no masks, no MSE;
- ``apply_ccm``: correcting the 224 × 172 frame.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import colour as colour_science  # noqa: E402

from benchmarks.common import print_table, time_it  # noqa: E402
from rgbd_envmap.colour import apply_ccm, ccm_sums, estimate_ccm  # noqa: E402


def _numpy_normal(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, float]:
    a, b = src.astype(np.float64), dst.astype(np.float64)
    keep = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1) & ~(a >= 1.0).any(axis=1)
    a, b = a[keep], b[keep]
    x = np.linalg.solve(a.T @ a, a.T @ b)
    return x.T, float(np.mean((a @ x - b) ** 2))


def _numpy_tuned(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, float]:
    """The numpy version with its slow spots removed: per-row masks from column compares and one gemv
    (``.all(axis=1)`` over a length-3 axis costs ~0.7 ms at this size), no fancy indexing when every row
    is kept, and one (N, 6)ᵀ(N, 6) product for AᵀA, AᵀB and BᵀB with the MSE from the sums."""
    ab = np.concatenate([src, dst], axis=1, dtype=np.float64)
    keep = np.isfinite(ab @ np.ones(6)) & (ab[:, 0] < 1.0) & (ab[:, 1] < 1.0) & (ab[:, 2] < 1.0)
    if not keep.all():
        ab = ab[keep]
    g = ab.T @ ab
    ata, atb = g[:3, :3], g[:3, 3:]
    x = np.linalg.solve(ata, atb)
    sse = np.trace(g[3:, 3:]) - 2.0 * np.sum(x * atb) + np.sum(x * (ata @ x))
    return x.T, float(max(sse, 0.0) / (3 * len(ab)))


def _numpy_lstsq(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, float]:
    a, b = src.astype(np.float64), dst.astype(np.float64)
    keep = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1) & ~(a >= 1.0).any(axis=1)
    a, b = a[keep], b[keep]
    x, residuals, _, _ = np.linalg.lstsq(a, b, rcond=None)
    return x.T, float(residuals.sum() / b.size)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=500)
    parser.add_argument("--n-pairs", type=int, default=38_528)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    numba.set_num_threads(1)

    rng = np.random.default_rng(0)
    n = args.n_pairs
    true_m = np.array([[1.1, 0.04, -0.02], [0.03, 0.95, 0.02], [-0.03, 0.05, 1.3]])
    src = rng.uniform(0.0, 0.95, (n, 3)).astype(np.float32)
    dst = (src @ true_m.T + 0.002 * rng.standard_normal((n, 3))).astype(np.float32)
    frame = src.reshape(-1, 172, 3) if n % 172 == 0 else src

    # The fast paths must agree with each other before they are timed.
    ours = estimate_ccm(src, dst)
    alternatives = {
        "numpy normal": _numpy_normal(src, dst),
        "numpy tuned": _numpy_tuned(src, dst),
        "numpy lstsq": _numpy_lstsq(src, dst),
    }
    for name, (m, mse) in alternatives.items():
        dm, dmse = np.abs(m - ours.matrix).max(), abs(mse - ours.mse)
        print(f"{name} vs estimate_ccm: max |ΔM| = {dm:.1e}, |Δmse| = {dmse:.1e}")
        assert dm < 1e-9 and dmse < 1e-12

    r = args.repeats
    slow = max(10, r // 10)
    rows = {
        f"estimate_ccm least_squares ({n} pairs)": time_it(lambda: estimate_ccm(src, dst), r, warmup=3),
        "  numba sums only": time_it(lambda: ccm_sums(src, dst, 1.0), r, warmup=3),
        "numpy normal equations + MSE": time_it(lambda: _numpy_normal(src, dst), slow),
        "numpy normal equations + MSE, tuned": time_it(lambda: _numpy_tuned(src, dst), r, warmup=3),
        "numpy lstsq + MSE": time_it(lambda: _numpy_lstsq(src, dst), slow),
        "estimate_ccm 'Cheung 2004'": time_it(lambda: estimate_ccm(src, dst, "Cheung 2004"), slow),
        "estimate_ccm 'Finlayson 2015'": time_it(lambda: estimate_ccm(src, dst, "Finlayson 2015"), slow),
        "colour-science matrix_colour_correction": time_it(
            lambda: colour_science.characterisation.matrix_colour_correction(src, dst, method="Cheung 2004"), slow
        ),
        f"apply_ccm {frame.shape[0]}x{frame.shape[1]}": time_it(lambda: apply_ccm(frame, ours.matrix), r),
    }
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
