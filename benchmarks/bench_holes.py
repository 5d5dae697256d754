"""Time hole filling (paper 003 §4.2, eq. 1, and the two baselines) on a 224×172 ToF-sized frame.

    python benchmarks/bench_holes.py [--repeats N] [--session DIR] [--json PATH]

Two masks with 30 % of the pixels unknown: i.i.d. random pixels, and a few large discs ("blobs",
the shape emitters and screens leave). Numba and OpenCV are both held to one thread. Beside the
library's methods it times ``numpy eq1``: eq. (1) written with whole-array numpy operations (running
maxima of source indices along each direction, diagonals sheared into columns), to show what the numba
kernel buys. Its results are checked against the library before timing. Session rows: the RGB-D
frames of eight depth frames of the recorded default session (``runs/default/session``, skipped when
absent; bench_ingest.session_frames), cycled. ``monroy2018 max_source_ratio=1.5`` rows: eq. (1) with
the ingest's guard against fills across depth edges, right after the plain eq. (1) rows.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.bench_ingest import DEFAULT_SESSION, cycling, session_frames  # noqa: E402
from benchmarks.common import print_table, time_it  # noqa: E402
from rgbd_envmap.depth import FILL_METHODS, fill_holes  # noqa: E402

H, W = 172, 224
HOLE_FRACTION = 0.30
#: the Tango ingest's default ``fill_max_source_ratio``, timed beside the plain eq. (1).
RATIO = 1.5


def iid_mask(rng: np.random.Generator) -> np.ndarray:
    """Known mask with exactly 30 % of the pixels unknown, chosen uniformly."""
    known = np.ones(H * W, bool)
    known[rng.choice(H * W, round(HOLE_FRACTION * H * W), replace=False)] = False
    return known.reshape(H, W)


def blob_mask(rng: np.random.Generator) -> np.ndarray:
    """Known mask whose unknown pixels are a few discs (radius 20–45 px) covering ≈ 30 %."""
    yy, xx = np.mgrid[:H, :W]
    known = np.ones((H, W), bool)
    while 1.0 - known.mean() < HOLE_FRACTION:
        cy, cx, r = rng.integers(0, H), rng.integers(0, W), rng.integers(20, 46)
        known &= (yy - cy) ** 2 + (xx - cx) ** 2 > r * r
    return known


def numpy_eq1(depth: np.ndarray, known: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (1) with numpy only: for each direction, arrange the image so the sources lie above each
    pixel in its column, take the running maximum of known rows down each column (nearest source at
    or above), shift by one row (strictly above) and weight by the distance."""
    h, w = depth.shape
    values = np.where(known, depth, 0.0).astype(np.float64)
    num = np.zeros((h, w))
    den = np.zeros((h, w))

    def shear(a, anti, fill):  # diagonals → columns: column x − y + h − 1 (or x + y)
        out = np.full((h, w + h - 1), fill, a.dtype)
        rows = np.arange(h)[:, None]
        cols = (np.arange(w)[None, :] + rows) if anti else (np.arange(w)[None, :] - rows + h - 1)
        out[rows, cols] = a
        return out, rows, cols

    def from_above(k, v, step):
        n = k.shape[0]
        rows = np.arange(n)[:, None]
        last = np.maximum.accumulate(np.where(k, rows, -1), axis=0)
        above = np.vstack([np.full((1, k.shape[1]), -1), last[:-1]])
        dist = (rows - above) * step
        weight = np.where(above >= 0, np.maximum(0.0, (w - dist) / w), 0.0)
        return weight * np.take_along_axis(v, np.maximum(above, 0), axis=0), weight

    for flip in (False, True):  # sources above, then (flipped) below
        k = known[::-1] if flip else known
        v = values[::-1] if flip else values
        parts = [from_above(k, v, 1.0)]
        for anti in (False, True):
            ks, rows, cols = shear(k, anti, False)
            vs, _, _ = shear(v, anti, 0.0)
            n_s, d_s = from_above(ks, vs, np.sqrt(2.0))
            parts.append((n_s[rows, cols], d_s[rows, cols]))
        for n_p, d_p in parts:
            num += n_p[::-1] if flip else n_p
            den += d_p[::-1] if flip else d_p
    for flip in (False, True):  # sources left, then right: the transposed image, same width scale
        k = known.T[::-1] if flip else known.T
        v = values.T[::-1] if flip else values.T
        n_p, d_p = from_above(k, v, 1.0)
        num += (n_p[::-1] if flip else n_p).T
        den += (d_p[::-1] if flip else d_p).T
    after = known | (den > 0)
    out = np.where(known, depth, np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)).astype(np.float32)
    return out, after


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=100, help="timed runs per case (≥ 50 recommended)")
    parser.add_argument("--session", type=Path, default=DEFAULT_SESSION, help="a recorded session (rgbd-envmap simulate)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    numba.set_num_threads(1)  # the kernel is serial anyway; this pins any threading layer too
    cv2.setNumThreads(1)
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:H, :W]
    depth = (1.5 + 0.004 * xx + 0.002 * yy + 0.01 * rng.standard_normal((H, W))).astype(np.float32)

    rows = {}
    for mask_name, known in (("iid", iid_mask(rng)), ("blobs", blob_mask(rng))):
        holed = np.where(known, depth, np.nan).astype(np.float32)
        ref, ref_after = fill_holes(holed, known)
        got, got_after = numpy_eq1(holed, known)
        if not (np.array_equal(ref_after, got_after) and np.allclose(ref, got, rtol=0, atol=1e-5)):
            raise RuntimeError(f"numpy eq1 disagrees with fill_holes on the {mask_name} mask")
        hole_pct = 100.0 * (1.0 - known.mean())
        for method in FILL_METHODS:
            rows[f"{method} {mask_name} {hole_pct:.0f}%"] = time_it(lambda m=method: fill_holes(holed, known, m),
                                                                    args.repeats, warmup=3)
        rows[f"monroy2018 max_source_ratio={RATIO} {mask_name} {hole_pct:.0f}%"] = time_it(
            lambda: fill_holes(holed, known, max_source_ratio=RATIO), args.repeats, warmup=3)
        rows[f"numpy eq1 {mask_name} {hole_pct:.0f}%"] = time_it(lambda: numpy_eq1(holed, known),
                                                               args.repeats, warmup=3)
    frames = session_frames(args.session)
    if frames is None:
        print(f"no session at {args.session}: session rows skipped (rgbd-envmap simulate writes one)")
    else:
        unknown = 100 * (1 - np.mean([f.frame.known.mean() for f in frames]))
        for method in FILL_METHODS:
            rows[f"{method} session frames ({unknown:.1f} % unknown)"] = time_it(
                cycling(frames, lambda f, m=method: fill_holes(f.frame.depth_m, f.frame.known, m)), args.repeats, warmup=3)
            if method == "monroy2018":
                rows[f"monroy2018 max_source_ratio={RATIO} session frames"] = time_it(
                    cycling(frames, lambda f: fill_holes(f.frame.depth_m, f.frame.known, max_source_ratio=RATIO)),
                    args.repeats, warmup=3)
    print(f"fill_holes on {W}x{H}, numba threads = {numba.get_num_threads()}, cv2 threads = {cv2.getNumThreads()}")
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
