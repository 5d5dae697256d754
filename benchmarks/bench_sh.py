"""Time the SH stage (paper 003 §7.1, DESIGN.md §4 stage 8) on the 2000×1000 environment map.

    python benchmarks/bench_sh.py [--repeats N] [--json PATH]

Cases: ``project_equirect`` with every pixel valid and with 5 % of the pixels missing (i.i.d.), the
stage-8 fill alone on that mask, ``basis`` and ``irradiance`` of 35k normals (a typical mesh). The
issue's target is a median ≤ 3 ms for the all-valid projection. BLAS and numba are held to one thread
(the environment variables are set before numpy is imported).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, time_it
from rgbd_envmap import sh

H, W = 1000, 2000
N_NORMALS = 35_000
MISSING_FRACTION = 0.05


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    radiance = rng.uniform(0, 2, (H, W, 3)).astype(np.float32)
    valid = rng.uniform(size=(H, W)) >= MISSING_FRACTION
    normals = rng.normal(size=(N_NORMALS, 3))
    coeffs = sh.project_equirect(radiance)

    rows = {
        "project_equirect 2000x1000 all valid": time_it(lambda: sh.project_equirect(radiance), args.repeats),
        "project_equirect 2000x1000 5% missing": time_it(
            lambda: sh.project_equirect(radiance, valid), args.repeats),
        "  of which fill_missing": time_it(lambda: sh.fill_missing(radiance, valid), args.repeats),
        "basis 35k normals, 5 bands": time_it(lambda: sh.basis(normals, 5), args.repeats),
        "irradiance 35k normals, 5 bands": time_it(lambda: sh.irradiance(coeffs, normals), args.repeats),
    }
    print(f"one thread; {args.repeats} repeats after 1 warm-up")
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
