"""Time the PRT stage (paper 003 §7.1; docs/design/overview.md, stage 9): per-frame shading and shadow alpha, and
the one-off costs (object load, transfer precompute, shadow plane, cache hits).

    python benchmarks/bench_prt.py [--repeats N] [--precompute-repeats N] [--object bunny] [--session-map NPZ] [--json PATH]

Per frame (the issue's target: ``shade`` ≤ 0.5 ms median for 35k vertices × 25 coefficients):
``prt.shade`` of the object at 3, 5 and 8 bands, of 35,000 rows × 25 (float32, C-contiguous), of a
column slice ``transfer[:, :9]``, and ``prt.shadow_alpha`` of a 48×48 plane. One-off: the cached
object load, ``compute_transfer`` of the whole object (1024 directions, 5 bands), ``shadow_plane``
(48×48 on 0.5 m), and ``load_or_compute`` hitting the cache. BLAS and numba are held to one thread;
open3d's ray casting uses every core (two here).

Session rows: the pipeline's "Shade object (PRT)" stage as the pipeline runs it (``shade`` of the
5-band transfer into a reused buffer, then ``shadow_alpha`` of the 48×48 plane), with the 5-band SH
coefficients of the map captured by the default session (``runs/default/envmap.npz``, written by
``rgbd-envmap simulate``; random coefficients when absent).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, time_it
from rgbd_envmap import assets, prt, sh

DEFAULT_SESSION_MAP = Path(__file__).resolve().parent.parent / "runs" / "default" / "envmap.npz"

N_DIRS = 1024


def session_rows(T5: np.ndarray, obj, plane, session_map: Path, repeats: int) -> dict[str, dict]:
    """The pipeline's shading stage with the default session's lighting (see the module docstring)."""
    if session_map.is_file():
        with np.load(session_map) as npz:
            L = sh.project_equirect(np.where(npz["valid"][..., None], npz["radiance"], 0), bands=5)
        source = "session SH"
    else:
        L = np.random.default_rng(1).normal(size=(25, 3))
        source = "random SH: no session map"
    buffers = [np.empty((len(T5), 3), np.float32) for _ in range(2)]
    state = {"i": 0}

    def stage():  # as the pipeline shades: two output buffers swapped per call, then the plane's alpha
        state["i"] ^= 1
        prt.shade(T5, L, obj.albedo, out=buffers[state["i"]])
        prt.shadow_alpha(plane, L)

    return {
        f"session: 'Shade object (PRT)' {len(T5)} x 25 + alpha ({source})": time_it(stage, repeats),
        f"session:   shade {len(T5)} x 25, out=": time_it(lambda: prt.shade(T5, L, obj.albedo, out=buffers[0]), repeats),
        "session:   shadow_alpha 48x48": time_it(lambda: prt.shadow_alpha(plane, L), repeats),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=300)
    parser.add_argument("--precompute-repeats", type=int, default=3)
    parser.add_argument("--object", default="bunny", choices=assets.OBJECT_NAMES)
    parser.add_argument("--session-map", type=Path, default=DEFAULT_SESSION_MAP,
                        help="the captured map of a session (its radiance and valid mask) for the session rows")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    obj = assets.load_virtual_object(args.object)
    V = len(obj.vertices)
    rng = np.random.default_rng(0)
    coeffs = rng.normal(size=(64, 3))
    with tempfile.TemporaryDirectory() as tmp:
        transfer = prt.load_or_compute(obj, 8, n_dirs=N_DIRS, cache_dir=tmp)
        plane = prt.shadow_plane(obj, size_m=0.5, resolution=48, bands=5, n_dirs=N_DIRS, cache_dir=tmp)
        T5 = np.ascontiguousarray(transfer[:, :25])
        T3, T8 = np.ascontiguousarray(transfer[:, :9]), np.ascontiguousarray(transfer)
        T35k = rng.uniform(-1, 1, (35_000, 25)).astype(np.float32)
        out = np.empty((V, 3), np.float32)
        r, pr = args.repeats, args.precompute_repeats
        rows = {
            f"shade {V} x 9 (3 bands)": time_it(lambda: prt.shade(T3, coeffs[:9], obj.albedo), r),
            f"shade {V} x 25 (5 bands)": time_it(lambda: prt.shade(T5, coeffs[:25], obj.albedo), r),
            f"shade {V} x 25, out=": time_it(lambda: prt.shade(T5, coeffs[:25], obj.albedo, out=out), r),
            f"shade {V} x 64 (8 bands)": time_it(lambda: prt.shade(T8, coeffs, obj.albedo), r),
            "shade 35000 x 25 (issue target <= 0.5 ms)": time_it(lambda: prt.shade(T35k, coeffs[:25], obj.albedo), r),
            f"shade {V} x 64 transfer, 9 coeffs (column slice)": time_it(
                lambda: prt.shade(T8, coeffs[:9], obj.albedo), r),
            "shadow_alpha 48x48 plane, 25 coeffs": time_it(lambda: prt.shadow_alpha(plane, coeffs[:25]), r),
            **session_rows(T5, obj, plane, args.session_map, r),
            "load_virtual_object (cached mesh)": time_it(lambda: assets.load_virtual_object(args.object), 20),
            f"load_or_compute {V} x 64, cache hit": time_it(
                lambda: prt.load_or_compute(obj, 8, n_dirs=N_DIRS, cache_dir=tmp), 20),
            f"compute_transfer {V} vertices, {N_DIRS} dirs, 5 bands": time_it(
                lambda: prt.compute_transfer(obj.vertices, obj.normals, obj.faces, 5, n_dirs=N_DIRS), pr, warmup=0),
            f"shadow_plane 48x48, {N_DIRS} dirs, 5 bands (no cache)": time_it(
                lambda: prt.shadow_plane(obj, size_m=0.5, resolution=48, n_dirs=N_DIRS, use_cache=False), pr,
                warmup=0),
        }
    print(f"object: {obj}")
    print(f"BLAS one thread; per-frame cases {args.repeats} repeats after 1 warm-up; precompute {pr} repeats")
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
