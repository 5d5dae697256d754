"""Time the equirect metrics (WS-PSNR, sphere-weighted correlation, coverage) on a 2000×1000 EM.

    python benchmarks/bench_metrics.py [--repeats N] [--json PATH]

Inputs: 1000×2000×3 float32 maps (the pipeline's EM size, docs/design/overview.md, stage 6), without a mask
and with a random mask of ~90 % valid pixels. Beside the library it times ``whole-map numpy``: the
same formulas written with whole-map float64 temporaries (the straightforward numpy version), to show
what the library's cache-sized row blocks buy. Its results are checked against the library before
timing. Single process; numpy's BLAS may use more than one thread for the dot products.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, time_it  # noqa: E402

from rgbd_envmap import metrics  # noqa: E402
from rgbd_envmap.geometry import equirect_solid_angles  # noqa: E402

H, W, C = 1000, 2000, 3
VALID_FRACTION = 0.9


def whole_map_ws_psnr(a: np.ndarray, b: np.ndarray, valid: np.ndarray | None) -> float:
    sa = equirect_solid_angles(*a.shape[:2])
    d = np.subtract(a, b, dtype=np.float64)
    sq = np.einsum("hwc,hwc->hw", d, d)
    wts = sa if valid is None else sa * valid
    return 10 * math.log10(a.shape[2] * wts.sum() / np.sum(wts * sq))


def whole_map_correlation(a: np.ndarray, b: np.ndarray, valid: np.ndarray | None) -> float:
    sa = equirect_solid_angles(*a.shape[:2])
    if valid is None:
        av, bv, wv = a.reshape(-1, a.shape[2]), b.reshape(-1, b.shape[2]), sa.reshape(-1)
    else:
        av, bv, wv = a[valid], b[valid], sa[valid]
    da = av - (wv @ av) / wv.sum()
    db = bv - (wv @ bv) / wv.sum()
    wda = da * wv[:, None]
    r = np.einsum("nc,nc->c", wda, db) / np.sqrt(
        np.einsum("nc,nc->c", wda, da) * np.einsum("nc,nc->c", db * wv[:, None], db))
    return float(r.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    a = rng.random((H, W, C), dtype=np.float32)
    b = (a + 0.05 * rng.standard_normal((H, W, C), dtype=np.float32)).astype(np.float32)
    valid = rng.random((H, W)) < VALID_FRACTION
    equirect_solid_angles(H, W)  # geometry's cache, filled once as in a pipeline run

    for mask in (None, valid):
        lib, ref = metrics.ws_psnr(a, b, mask), whole_map_ws_psnr(a, b, mask)
        if not math.isclose(lib, ref, rel_tol=1e-10):
            raise SystemExit(f"ws_psnr disagrees with the whole-map version: {lib} vs {ref}")
        lib, ref = metrics.sphere_correlation(a, b, mask), whole_map_correlation(a, b, mask)
        if not math.isclose(lib, ref, rel_tol=1e-10):
            raise SystemExit(f"sphere_correlation disagrees with the whole-map version: {lib} vs {ref}")

    r = args.repeats
    rows = {
        "ws_psnr": time_it(lambda: metrics.ws_psnr(a, b), r),
        "ws_psnr valid": time_it(lambda: metrics.ws_psnr(a, b, valid), r),
        "ws_psnr whole-map numpy": time_it(lambda: whole_map_ws_psnr(a, b, None), r),
        "ws_psnr valid whole-map numpy": time_it(lambda: whole_map_ws_psnr(a, b, valid), r),
        "sphere_correlation": time_it(lambda: metrics.sphere_correlation(a, b), r),
        "sphere_correlation valid": time_it(lambda: metrics.sphere_correlation(a, b, valid), r),
        "sphere_correlation whole-map numpy": time_it(lambda: whole_map_correlation(a, b, None), max(3, r // 3)),
        "sphere_correlation valid whole-map numpy": time_it(lambda: whole_map_correlation(a, b, valid), max(3, r // 3)),
        "coverage": time_it(lambda: metrics.coverage(valid), r),
        "data_loss": time_it(lambda: metrics.data_loss(valid, np.roll(valid, 1, axis=1)), r),
    }
    print(f"{H}×{W}×{C} float32, valid mask {VALID_FRACTION:.0%}")
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps({"size": [H, W, C], "dtype": "float32", "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
