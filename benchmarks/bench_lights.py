"""Time the light samplers (rgbd_envmap.lights; paper 002 Table 1) on a 2000×1000 map, beside the
paper's Nokia N900 figures, with the irradiance error of each light set ("speed beside error").

    python benchmarks/bench_lights.py [--repeats N] [--json PATH]

The map is ``rgbd_envmap.reference.lights.room_map(1000, 2000)``: a room with dim walls, a window and a
small ceiling lamp (1.9 m above the map's origin). Every case is timed round-robin (one call of each
case per round, ``--repeats`` rounds after two warm-up calls), so load from other processes on this
shared machine hits all cases alike; the table gives the median and p95 per call. numba and BLAS are
held to one thread.

Cases: each method × 200 / 1000 / 10 000 lights from scratch; the Q2-Tree fed frame after frame
(``Q2TreeState``, the lamp flickering by ±5 % between frames) and with a finest level one deeper
than the default (8: quads of about one pixel); Hemigon with its filters (``HemigonState``); the
Q2-Tree with the map's depth (positions); the direct / indirect split on the full map; what the
pipeline runs per relight: the 500×250 light grid taken from the map (``light_grid``) and its
direct part with the direct pixels' 5-band SH (``direct_part``, by a basis table and separably);
virtual area lights (``"val"``, paper 000) on that grid's direct part at τ = 0.2 and 0.5, as the
pipeline calls them (12 lights, the default, and 48; cold and warm-started from an ``AreaLightState``),
and 200 of them on the whole grid (with its error).

Error: the relative RMS, over 64 Fibonacci normals, of the luminance of the irradiance the lights
give against the brute-force clamped-cosine convolution of the map (every pixel), the same for every
round (the samplers are deterministic).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rgbd_envmap.lights import (AreaLightState, HemigonState, Q2TreeState, direct_part, irradiance, light_grid, sample_lights,
                                split_direct_indirect)
from rgbd_envmap.reference import lights as ref

#: paper 002 Table 1, Nokia N900, 360×90 hemisphere map (Q2-Tree: 12×100×100 HEALPix), ms.
PAPER_MS = {("pharr", 200): 10, ("pharr", 1000): 10, ("pharr", 10000): 80,
            ("hemigon", 200): 150, ("hemigon", 1000): 150, ("hemigon", 10000): 170,
            ("q2tree", 200): 30, ("q2tree", 1000): 50, ("q2tree", 10000): 430}


def fibonacci_normals(m: int = 64) -> np.ndarray:
    k = np.arange(m) + 0.5
    z = 1 - 2 * k / m
    ph = np.pi * (1 + 5 ** 0.5) * k
    return np.stack([np.sqrt(1 - z * z) * np.cos(ph), np.sqrt(1 - z * z) * np.sin(ph), z], 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    rad, dep, org = ref.room_map(1000, 2000)
    flicker = [rad, rad.copy()]
    flicker[1][rad[..., 0] > 100] *= np.float32(1.05)
    counters = {"q2tree": -1, "hemigon": -1}  # each state case's first call (its error) gets the map itself

    def next_frame(case):
        counters[case] += 1
        return flicker[counters[case] % 2]

    q2_state, hemi_state = Q2TreeState(), HemigonState()
    from rgbd_envmap import sh
    from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles

    sub = light_grid(rad, 4)  # the pipeline's sub-grid (a basis table for the full map: 400 MB)
    H, W = sub.shape[:2]
    basis_table = sh.basis(equirect_directions(H, W).reshape(-1, 3), 5) * equirect_solid_angles(H, W).reshape(-1, 1)
    cases = {}
    for method in ("pharr", "hemigon", "q2tree"):
        for n in (200, 1000, 10000):
            cases[f"{method} n={n}"] = (lambda m=method, k=n: sample_lights(rad, k, m), method, n)
    cases["q2tree n=1000 state (flicker)"] = (lambda: sample_lights(next_frame("q2tree"), 1000, "q2tree", state=q2_state),
                                              None, None)
    cases["q2tree n=1000 level=8"] = (lambda: sample_lights(rad, 1000, "q2tree", level=8), None, None)
    cases["q2tree n=10000 level=8"] = (lambda: sample_lights(rad, 10000, "q2tree", level=8), None, None)
    cases["hemigon n=1000 state"] = (lambda: sample_lights(next_frame("hemigon"), 1000, "hemigon", state=hemi_state),
                                     None, None)
    cases["q2tree n=1000 + depth"] = (lambda: sample_lights(rad, 1000, "q2tree", depth_m=dep, origin=org), None, None)
    cases["split tau=0.5"] = (lambda: split_direct_indirect(rad, 0.5), None, None)
    cases["direct_part 500×250 SH table"] = (
        lambda: direct_part(sub, 0.5, basis_table), None, None)
    cases["direct_part 500×250 SH separable"] = (
        lambda: direct_part(sub, 0.5, 5), None, None)
    cases["light_grid stride 4"] = (lambda: light_grid(rad, 4), None, None)
    # virtual area lights as the pipeline runs them: on the light grid's direct part, with its depth
    sub_dep = np.ascontiguousarray(dep[::4, ::4])
    for tau in (0.2, 0.5):
        mask = direct_part(sub, tau, 5)[0]
        for n in (12, 48):
            cases[f"val n={n} 500×250 direct tau={tau}"] = (
                lambda m=mask, k=n: sample_lights(sub, k, "val", valid=m, depth_m=sub_dep, origin=org), None, None)
    val_state, mask_02 = AreaLightState(), direct_part(sub, 0.2, 5)[0]
    cases["val n=12 500×250 direct tau=0.2 state"] = (
        lambda: sample_lights(sub, 12, "val", valid=mask_02, depth_m=sub_dep, origin=org, state=val_state), None, None)
    cases["val n=200 500×250 whole map"] = (
        lambda: sample_lights(sub, 200, "val", depth_m=sub_dep, origin=org), None, None)

    normals = fibonacci_normals(64)
    truth = ref.brute_force_irradiance(rad, normals) @ ref.LUMINANCE
    errors = {}
    for name, (fn, method, n) in cases.items():
        out = fn()
        if hasattr(out, "directions") and "direct" not in name:  # a direct part's lights miss the rest
            got = irradiance(out, normals) @ ref.LUMINANCE
            errors[name] = (float(np.sqrt(np.mean((got - truth) ** 2)) / np.sqrt(np.mean(truth ** 2))), len(out))
    for fn, _, _ in cases.values():
        fn()  # second warm-up
    times = {name: [] for name in cases}
    for _ in range(args.repeats):
        for name, (fn, _, _) in cases.items():
            t0 = time.perf_counter()
            fn()
            times[name].append((time.perf_counter() - t0) * 1e3)

    rows = []
    print(f"{'case':<32} {'lights':>6} {'median ms':>10} {'p95 ms':>8} {'N900 ms':>8} {'irr. err':>9}")
    for name, (_, method, n) in cases.items():
        t = np.asarray(times[name])
        paper = PAPER_MS.get((method, n))
        err, count = errors.get(name, (None, None))
        rows.append({"case": name, "lights": count, "median_ms": float(np.median(t)),
                     "p95_ms": float(np.percentile(t, 95)), "paper_n900_ms": paper, "irradiance_rel_rms": err})
        print(f"{name:<32} {'' if count is None else count:>6} {np.median(t):>10.2f} {np.percentile(t, 95):>8.2f} "
              f"{'' if paper is None else paper:>8} {'' if err is None else f'{100 * err:.2f} %':>9}")
    if args.json:
        args.json.write_text(json.dumps({"map": "room_map(1000, 2000)", "repeats": args.repeats, "rows": rows},
                                        indent=1))


if __name__ == "__main__":
    main()
