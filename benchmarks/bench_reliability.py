"""Time reliability marking (paper 003 §5.2) on a 224×172 RGB-D frame, one thread.

    python benchmarks/bench_reliability.py [--repeats N] [--session DIR] [--json PATH]

Cases: ``mark_reliable`` with each method (numba kernels, the library's code) and, for comparison,
vectorised numpy versions of the same two statistics (the reason the library uses numba). The input
is a noisy simulated-like frame: a slanted wall with a box in front, 1 % range noise, two unknown
regions and 0.5 % unknown speckle, a few dark and bright pixels. Numba is pinned to one thread
(``NUMBA_NUM_THREADS=1``), as the kernels are serial anyway. Session rows: the RGB-D frames of eight
depth frames of the recorded default session (``runs/default/session``; bench_ingest.session_frames),
cycled, and ``discontinuity_test`` on their hole-filled frames (all outputs, as the capture stage
calls it).
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.bench_ingest import DEFAULT_SESSION, cycling, session_frames  # noqa: E402
from benchmarks.common import print_table, time_it  # noqa: E402
from rgbd_envmap.depth.reliability import (  # noqa: E402
    MIN_NEIGHBOURS_DEFAULT,
    MONROY2018_THRESHOLD,
    _chi2_thresholds,
    discontinuity_test,
    exposure_ok,
    mark_reliable,
)

_OFFSETS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)]


def _shifted(a: np.ndarray, dr: int, dc: int, fill) -> np.ndarray:
    """``out[r, c] = a[r + dr, c + dc]``, ``fill`` outside the image."""
    h, w = a.shape
    out = np.full_like(a, fill)
    out[max(0, -dr):h - max(0, dr), max(0, -dc):w - max(0, dc)] = a[max(0, dr):h + min(0, dr), max(0, dc):w + min(0, dc)]
    return out


def noise_model_statistic_numpy(depth_m, valid, noise_rel=0.01, noise_abs_m=0.0, fit="inverse"):
    """Vectorised numpy plane-fit χ² (the ``noise_model`` statistic) → (T (H, W), n_neighbours (H, W)).

    ``fit="inverse"`` fits 1/z as the library does; ``fit="z"`` fits z itself with σ_z, which the
    study uses to measure the curvature error of that shortcut. T is 0 where fewer than 3 neighbours.
    """
    z = np.where(valid, depth_m, 1.0).astype(np.float64)
    if fit == "inverse":
        val, sig = 1.0 / z, (noise_abs_m + noise_rel * z) / (z * z)
    else:
        val, sig = z, noise_abs_m + noise_rel * z
    ref, sref = val, sig  # centre value and σ (conditioning only, as in the kernel)
    ys, ws, us, vs = [], [], [], []
    for dr, dc in _OFFSETS:
        ok = _shifted(valid, dr, dc, False)
        y = (_shifted(val, dr, dc, 0.0) - ref) / sref
        s = _shifted(sig, dr, dc, 1.0) / sref
        ws.append(np.where(ok, 1.0 / (s * s), 0.0))
        ys.append(np.where(ok, y, 0.0))
        us.append(float(dc))
        vs.append(float(dr))
    W = np.stack(ws)
    Y = np.stack(ys)
    u = np.array(us)[:, None, None]
    v = np.array(vs)[:, None, None]
    s0, su, sv = W.sum(0), (W * u).sum(0), (W * v).sum(0)
    suu, svv, suv = (W * u * u).sum(0), (W * v * v).sum(0), (W * u * v).sum(0)
    sy, suy, svy = (W * Y).sum(0), (W * u * Y).sum(0), (W * v * Y).sum(0)
    c00, c01, c02 = suu * svv - suv * suv, sv * suv - su * svv, su * suv - sv * suu
    c11, c12, c22 = s0 * svv - sv * sv, su * sv - s0 * suv, s0 * suu - su * su
    n_nb = (W > 0).sum(0) - 1
    testable = valid & (n_nb >= 3)
    det = np.where(testable, s0 * c00 + su * c01 + sv * c02, 1.0)
    b0 = (c00 * sy + c01 * suy + c02 * svy) / det
    b1 = (c01 * sy + c11 * suy + c12 * svy) / det
    b2 = (c02 * sy + c12 * suy + c22 * svy) / det
    t = (W * (Y - (b0 + b1 * u + b2 * v)) ** 2).sum(0)
    return np.where(testable, t, 0.0), np.where(valid, n_nb, 0)


def monroy2018_statistic_numpy(depth_m, valid):
    """Vectorised numpy Σ_known-neighbours (d_i − d)² / d → (S (H, W), n_neighbours (H, W))."""
    d = np.where(valid, depth_m, 1.0).astype(np.float64)
    s = np.zeros_like(d)
    n = np.zeros(d.shape, np.int64)
    for dr, dc in _OFFSETS:
        if dr == 0 and dc == 0:
            continue
        ok = _shifted(valid, dr, dc, False)
        diff = _shifted(d, dr, dc, 0.0) - d
        s += np.where(ok, diff * diff / d, 0.0)
        n += ok
    return np.where(valid, s, 0.0), np.where(valid, n, 0)


def required_neighbours(shape: tuple[int, int], min_neighbours: int) -> np.ndarray:
    """min(min_neighbours, in-image neighbours) per pixel: the library's border rule."""
    h, w = shape
    rr, cc = np.mgrid[0:h, 0:w]
    rows = np.minimum(rr + 1, h - 1) - np.maximum(rr - 1, 0) + 1
    cols = np.minimum(cc + 1, w - 1) - np.maximum(cc - 1, 0) + 1
    return np.minimum(min_neighbours, rows * cols - 1)


def mark_reliable_numpy(rgb, depth_m, known, method="noise_model", min_neighbours=None, p_value=0.05):
    """The whole of :func:`mark_reliable` in numpy (finite, positive depth assumed), for timing."""
    if min_neighbours is None:
        min_neighbours = MIN_NEIGHBOURS_DEFAULT[method]
    valid = known & np.isfinite(depth_m) & (depth_m > 0)
    if method == "noise_model":
        t, n_nb = noise_model_statistic_numpy(depth_m, valid)
        thr = _chi2_thresholds(p_value)[n_nb]
        enough = n_nb >= 3
    else:
        t, n_nb = monroy2018_statistic_numpy(depth_m, valid)
        thr = MONROY2018_THRESHOLD
        enough = True
    testable = valid & enough & (n_nb >= required_neighbours(depth_m.shape, min_neighbours))
    return testable & (t <= thr) & exposure_ok(rgb)


def make_frame(height: int = 172, width: int = 224, seed: int = 0):
    """A noisy 224×172 test frame: (rgb, depth_m, known)."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:height, 0:width]
    depth = 2.0 + 0.004 * (u - width / 2)  # slanted wall
    box = (abs(u - width / 2) < width / 6) & (abs(v - height / 2) < height / 5)
    depth = np.where(box, 1.2, depth) * (1.0 + 0.01 * rng.standard_normal((height, width)))
    known = rng.uniform(size=(height, width)) > 0.005  # speckle, and two dropout regions
    known[20:50, 30:70] = False
    known[120:140, 150:200] = False
    rgb = rng.uniform(0.0, 1.0, (height, width, 3)).astype(np.float32)
    rgb[rng.uniform(size=(height, width)) < 0.02] = 0.01
    rgb[rng.uniform(size=(height, width)) < 0.02] = 0.99
    return rgb, depth.astype(np.float32), known


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=300)
    parser.add_argument("--session", type=Path, default=DEFAULT_SESSION, help="a recorded session (rgbd-envmap simulate)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    rgb, depth, known = make_frame()
    # The numpy versions must agree with the library before their times mean anything.
    for method in ("noise_model", "monroy2018"):
        a = mark_reliable(rgb, depth, known, method)
        b = mark_reliable_numpy(rgb, depth, known, method)
        if np.count_nonzero(a != b) > 0:
            raise SystemExit(f"numpy and numba disagree for {method}: {np.count_nonzero(a != b)} pixels")
    rows = {}
    for method in ("noise_model", "monroy2018"):
        rows[f"mark_reliable {method} (numba) 224x172"] = time_it(lambda m=method: mark_reliable(rgb, depth, known, m), args.repeats, warmup=5)
        rows[f"mark_reliable {method} (numpy) 224x172"] = time_it(lambda m=method: mark_reliable_numpy(rgb, depth, known, m), max(20, args.repeats // 10), warmup=2)
    rows["exposure_ok alone 224x172"] = time_it(lambda: exposure_ok(rgb), args.repeats, warmup=5)
    frames = session_frames(args.session)
    if frames is None:
        print(f"no session at {args.session}: session rows skipped (rgbd-envmap simulate writes one)")
    else:
        for method in ("noise_model", "monroy2018"):
            rows[f"mark_reliable {method} session frames"] = time_it(
                cycling(frames, lambda f, m=method: mark_reliable(f.frame.rgb, f.frame.depth_m, f.frame.known, m)),
                args.repeats, warmup=5)
        rows["discontinuity_test session frames, filled (capture stage)"] = time_it(
            cycling(frames, lambda f: discontinuity_test(f.filled_depth, f.filled_known)), args.repeats, warmup=5)
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
